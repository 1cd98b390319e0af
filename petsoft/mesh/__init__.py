"""Meshes: reading and validating serial meshes, regions, probes, and the distributed mesh."""
