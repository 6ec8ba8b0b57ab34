"""Confirmatory experiments: plans sized for each open check, registered as a committed file
before any of their runs, and trained through the grid path."""
