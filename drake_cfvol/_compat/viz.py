"""Old name of :mod:`drake_cfvol.comanip.recording`."""
import sys

from drake_cfvol.comanip import recording as _module

sys.modules[__name__] = _module
