"""Old name of :mod:`drake_cfvol.scene.meshes`."""
import sys

from drake_cfvol.scene import meshes as _module

sys.modules[__name__] = _module
