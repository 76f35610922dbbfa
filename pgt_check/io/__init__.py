"""Readers for trajectory formats and images; each converts to the internal Trajectory model."""
