"""Maps and paths: occupancy grids, A*, point-to-point paths and shortest paths to targets."""
