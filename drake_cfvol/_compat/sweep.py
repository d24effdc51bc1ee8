"""Old name of :mod:`drake_cfvol.algorithm.sweep`."""
import sys

from drake_cfvol.algorithm import sweep as _module

sys.modules[__name__] = _module
