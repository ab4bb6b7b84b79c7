"""Run folders: the run log, locking, and the runner that plays one episode into a folder."""
