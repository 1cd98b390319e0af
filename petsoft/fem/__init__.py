"""Finite elements: the compiled element kernels, matrix assembly, Dirichlet conditions, and
the resolution of `where` selections (regions, expressions) to vertices, cells and faces."""
