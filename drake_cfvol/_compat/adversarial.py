"""Old name of :mod:`drake_cfvol.comanip.adversarial`."""
import sys

from drake_cfvol.comanip import adversarial as _module

sys.modules[__name__] = _module
