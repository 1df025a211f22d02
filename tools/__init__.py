"""Developer tools (not installed): generators for checked-in data files."""
