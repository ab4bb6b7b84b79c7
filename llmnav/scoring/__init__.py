"""Scoring runs: metrics, statistics, failure causes and every table `llmnav score` prints."""
