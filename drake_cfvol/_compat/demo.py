"""Old name of :mod:`drake_cfvol.apps.demo`."""
import sys

from drake_cfvol.apps import demo as _module

sys.modules[__name__] = _module
