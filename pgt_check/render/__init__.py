"""Rendering: load a mesh and render RGB + metric depth + coverage at a camera pose."""
