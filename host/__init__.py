"""The host: reads scenes, sets up the camera, drives rendering and writes images."""
