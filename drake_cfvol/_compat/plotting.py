"""Old name of :mod:`drake_cfvol.io.plotting`."""
import sys

from drake_cfvol.io import plotting as _module

sys.modules[__name__] = _module
