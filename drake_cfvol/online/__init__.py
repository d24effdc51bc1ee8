"""Bounds that follow a changing cell (docs/spec.md, SPEC 12): an obstacle
height map from a depth camera's points (:mod:`.obstacle_map`) and the
volume and bounds re-estimated from it, incrementally
(:mod:`.reestimate`)."""

from drake_cfvol.online.obstacle_map import MapGrid, ObstacleMap, PerceptionParams
from drake_cfvol.online.reestimate import BoundsUpdate, LiveBounds, OnlineBounds

__all__ = ["MapGrid", "ObstacleMap", "PerceptionParams", "BoundsUpdate", "LiveBounds", "OnlineBounds"]
