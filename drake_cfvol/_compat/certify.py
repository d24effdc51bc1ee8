"""Old name of :mod:`drake_cfvol.algorithm.certify`."""
import sys

from drake_cfvol.algorithm import certify as _module

sys.modules[__name__] = _module
