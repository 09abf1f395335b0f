"""Planning a mesh render: image rectangles and object cells (partition), cost cuts,
copies and holdings (balance), and the choice of mode and plan."""
