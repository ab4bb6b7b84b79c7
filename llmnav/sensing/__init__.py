"""Turning sensor data into text a model reads: LiDAR summaries, relevance, speech."""
