"""Old name of :mod:`drake_cfvol.algorithm.volume`."""
import sys

from drake_cfvol.algorithm import volume as _module

sys.modules[__name__] = _module
