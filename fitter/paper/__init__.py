"""Reproduction of the paper's Examples 1-3."""
