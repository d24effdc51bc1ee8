"""The benchmark harness (``harness.py``: the paper's Tables I and II side by
side, the certified rows, the adversarial section) and its committed results
(``default/``, ``adversarial/``). Not part of the library: run it as
``tools/dev.sh cfvol bench`` from a development checkout."""
