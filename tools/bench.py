"""Thin CLI over benchmarks/harness.py (same as `cfvol bench`)."""

import sys

from drake_cfvol.apps.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", *sys.argv[1:]]))
