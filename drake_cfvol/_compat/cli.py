"""Old name of :mod:`drake_cfvol.apps.cli`."""
import sys

from drake_cfvol.apps import cli as _module

sys.modules[__name__] = _module
