"""Finite elements: the compiled element kernels, matrix assembly and Dirichlet conditions."""
