"""The adversarial runs' push patterns, in a module that needs no Drake: the
CLI's ``--help`` lists them without loading it."""

__all__ = ["PATTERNS"]

#: Push patterns: "random" (a steady push with seeded signs: corner-seeking),
#: "nearest" (a steady push toward the nearest obstacle at a path position
#: the seed picks) or "random_pushes" (the ``<cell>_random`` scenario's
#: seeded sequence of random pushes, push seed = the run's seed).
PATTERNS = ("random", "nearest", "random_pushes")
