"""Non-LLM baselines every LLM run is compared against: occupancy grid, A*, oracle, frontier."""
