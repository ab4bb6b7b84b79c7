"""The ground floor: chat messages, geometry, robot specs, declarations, resources, plug-in discovery and safe files."""
