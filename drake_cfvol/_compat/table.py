"""Old name of :mod:`drake_cfvol.algorithm.table`."""
import sys

from drake_cfvol.algorithm import table as _module

sys.modules[__name__] = _module
