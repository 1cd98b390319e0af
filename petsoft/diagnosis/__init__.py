"""Mismatch analysis on arrays: noise level, where, when, which frequencies; the report."""
