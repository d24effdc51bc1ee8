"""Old name of :mod:`drake_cfvol.algorithm.pipeline`."""
import sys

from drake_cfvol.algorithm import pipeline as _module

sys.modules[__name__] = _module
