"""Mismatch analysis on arrays: noise level, where/when/which frequencies, and the diagnosis report."""
