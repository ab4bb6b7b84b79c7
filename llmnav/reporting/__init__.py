"""Turning run logs into the sources' tables, statistics and plots."""
