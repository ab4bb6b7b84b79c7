"""Typer commands: argument parsing and one call into the library each (import heavy modules lazily)."""
