"""Old name of :mod:`drake_cfvol.scene.arrays`."""
import sys

from drake_cfvol.scene import arrays as _module

sys.modules[__name__] = _module
