"""Old name of :mod:`drake_cfvol.scene.workcell`."""
import sys

from drake_cfvol.scene import workcell as _module

sys.modules[__name__] = _module
