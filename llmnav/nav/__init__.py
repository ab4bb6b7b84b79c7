"""The navigation layer: what moves a robot safely whatever commands it (the collision monitor)."""
