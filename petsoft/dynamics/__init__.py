"""Elastodynamics M q'' = f_el(q) + f_d(v) + f_ext(t): the discrete system and its integrators."""
