"""Running a render: in one process, on a local mesh of `meshnode` processes or on a
cluster (the mesh client), and the framebuffer the image gathers in."""
