"""Planning a mesh render: image rectangles and object cells (partition), cost cuts (balance,
from the pre-pass), copies and holdings (shared_cells, holding), and the choice of mode and
plan."""
