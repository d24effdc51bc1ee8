"""Old name of :mod:`drake_cfvol.algorithm.heightmap`."""
import sys

from drake_cfvol.algorithm import heightmap as _module

sys.modules[__name__] = _module
