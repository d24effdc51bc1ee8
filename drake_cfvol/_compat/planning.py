"""Old name of :mod:`drake_cfvol.algorithm.planning`."""
import sys

from drake_cfvol.algorithm import planning as _module

sys.modules[__name__] = _module
