"""The package's layers: its subpackages in pipeline order, each importing
only from those before it and from the base modules. The one list of them:
``tests/test_architecture.py`` checks the imports against it and
``tools/layout.py`` draws the guide's layout section (docs/layout.md) from it."""

#: Subpackages of ``drake_cfvol`` in pipeline order. A layer's own subpackages belong to it
#: (``kernel.kinds``; ``algorithm.certificate``, beyond the paper, which only the pipeline of the
#: method imports; ``systems.filter``, the safety filter, which imports only the systems' shared
#: helpers of its layer: ``tests/test_architecture.py`` checks both).
LAYERS = ("io", "kernel", "scene", "algorithm", "online", "systems", "comanip", "apps")

#: Top-level modules that import nothing of the package; every layer may use them.
BASE = ("exceptions", "_version", "_layers")
