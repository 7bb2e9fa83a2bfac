"""Reproduce Oh & Bernstein (2007) Examples 1-3 and print our figures beside the paper's.

Usage: python bench/reproduce_paper.py [--json] [--figures DIR] [--seeds N]
(the same as `duhem reproduce-paper`); see `fitter.paper.report`.
"""
from fitter.paper.report import main

if __name__ == "__main__":
    raise SystemExit(main())
