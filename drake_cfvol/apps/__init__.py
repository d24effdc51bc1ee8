"""Front ends: the ``cfvol`` command line and the demo. May import every other
subpackage.
"""
