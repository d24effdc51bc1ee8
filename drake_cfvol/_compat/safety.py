"""Old name of :mod:`drake_cfvol.systems.safety`."""
import sys

from drake_cfvol.systems import safety as _module

sys.modules[__name__] = _module
