"""Old name of :mod:`drake_cfvol.algorithm.reference`."""
import sys

from drake_cfvol.algorithm import reference as _module

sys.modules[__name__] = _module
