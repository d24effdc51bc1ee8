"""The certificate: what this package adds beyond the paper's method (the
rest of :mod:`drake_cfvol.algorithm`). It makes a bounds table's whole box
safe at every s, all joints at once (docs/certified.md).

- :mod:`.certify`: the certification (:class:`Certify`, :func:`certify_bounds`).
- :mod:`.boundary`: the proof of the box's edges and corners by the kernel's
  region tests; its regions (:mod:`.boundary_regions`) and cuts (:mod:`.cuts`).
- :mod:`.cert_cache`: certificates cached under a hash of their inputs.

Imports the method's table, sweep and metrics, ``scene``, ``kernel`` and ``io``.
"""
