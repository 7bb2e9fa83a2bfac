"""Reproduce Oh & Bernstein (2007) Examples 1-3 and print our figures beside the paper's.

Usage: python bench/reproduce_paper.py [--json] [--figures DIR] [--seeds N]
runs ``duhem reproduce-paper`` (`fitter.paper.report.command`).
"""

import sys

from fitter.cli import console

if __name__ == "__main__":
    console(["reproduce-paper", *sys.argv[1:]])
