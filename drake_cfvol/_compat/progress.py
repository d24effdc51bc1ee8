"""Old name of :mod:`drake_cfvol.io.progress`."""
import sys

from drake_cfvol.io import progress as _module

sys.modules[__name__] = _module
