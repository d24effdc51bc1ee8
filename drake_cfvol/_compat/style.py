"""Old name of :mod:`drake_cfvol.io.style`."""
import sys

from drake_cfvol.io import style as _module

sys.modules[__name__] = _module
