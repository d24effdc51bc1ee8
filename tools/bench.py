"""Thin CLI over drake_cfvol.bench (same as `cfvol bench`)."""
import sys

from drake_cfvol.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", *sys.argv[1:]]))
