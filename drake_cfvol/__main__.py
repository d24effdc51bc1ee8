"""``python -m drake_cfvol``: the ``cfvol`` command line."""

import sys

from drake_cfvol.apps.cli import main

sys.exit(main())
