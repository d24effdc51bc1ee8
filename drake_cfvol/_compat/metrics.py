"""Old name of :mod:`drake_cfvol.algorithm.metrics`."""
import sys

from drake_cfvol.algorithm import metrics as _module

sys.modules[__name__] = _module
