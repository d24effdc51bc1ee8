"""Old name of :mod:`drake_cfvol.io.records`."""
import sys

from drake_cfvol.io import records as _module

sys.modules[__name__] = _module
