"""The method: planning (RRT-Connect through OMPL), the height map and the
volume V, the sweep (joint bounding), the bounds table and its box-at-s
rule, the Drake reference backend, the certificate and its boundary proof,
CF and freedom, and the pipeline (Algorithm 1). Imports ``scene``,
``kernel`` and ``io``.
"""
