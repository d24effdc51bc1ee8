"""The method: planning (RRT-Connect through OMPL), the height map and the
volume V, the sweep (joint bounding), the bounds table and its box-at-s
rule, the Drake reference backend,
CF and freedom, and the pipeline (Algorithm 1). The certificate, beyond the paper, is
:mod:`drake_cfvol.algorithm.certificate`. Imports ``scene``,
``kernel`` and ``io``.
"""
