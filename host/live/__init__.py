"""The live view of `host render --serve`: a monitor of the render and the web server and
page that show it."""
