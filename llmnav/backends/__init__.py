"""Model backends: one file a backend, found through the `llmnav.backends` entry-point group."""
