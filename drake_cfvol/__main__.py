"""``python -m drake_cfvol``: the ``cfvol`` command line."""

import sys

from drake_cfvol.cli import main

sys.exit(main())
