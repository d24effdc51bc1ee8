"""Old name of :mod:`drake_cfvol.algorithm.boundary`."""
import sys

from drake_cfvol.algorithm import boundary as _module

sys.modules[__name__] = _module
