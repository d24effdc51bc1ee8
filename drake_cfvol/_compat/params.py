"""Old name of :mod:`drake_cfvol.scene.params`."""
import sys

from drake_cfvol.scene import params as _module

sys.modules[__name__] = _module
