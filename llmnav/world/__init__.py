"""What a scenario publishes: worlds, tasks, and what a planner may know of them."""
