"""The PyBullet simulation: world, robot, sensors and motion. It knows nothing of LLMs."""
