"""Old name of :mod:`drake_cfvol.algorithm._ompl`."""
import sys

from drake_cfvol.algorithm import _ompl as _module

sys.modules[__name__] = _module
