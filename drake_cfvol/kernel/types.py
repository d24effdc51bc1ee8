"""The kernel's constants (shape kinds, the shape row's layout) and its typed
arguments: named tuples of arrays, which numba takes as they are.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = [
    "MEMO_T",
    "MEMO_W",
    "Chain",
    "Model",
    "Blocks",
    "HeightField",
    "Scratch",
    "RegionScratch",
    "BOX",
    "SPHERE",
    "CAPSULE",
    "CYLINDER",
    "ELLIPSOID",
    "HULL",
    "SHAPE_W",
]


BOX, SPHERE, CAPSULE, CYLINDER, ELLIPSOID, HULL = 0, 1, 2, 3, 4, 5


SHAPE_W = 25


# Offsets in a shape row: its kind, centre (3), rotation (9, row-major),
# size (3), the hull's vertex range [first, end) in the vertex table, the
# motion's ball radius e_iso, axis u (3), disc radius e_disc and segment
# half-length e_seg (:func:`drake_cfvol.kernel.shapes.set_motion`).
ROW_KIND, ROW_CENTRE, ROW_ROTATION, ROW_SIZE = 0, 1, 4, 13
ROW_FIRST_VERTEX, ROW_END_VERTEX = 16, 17
ROW_E_ISO, ROW_AXIS, ROW_E_DISC, ROW_E_SEG = 18, 19, 22, 23
# The kernel's own short spellings, for index arithmetic in compiled code.
_K, _C, _R, _S = ROW_KIND, ROW_CENTRE, ROW_ROTATION, ROW_SIZE
_V0, _V1 = ROW_FIRST_VERTEX, ROW_END_VERTEX
_EI, _U, _ED, _ES = ROW_E_ISO, ROW_AXIS, ROW_E_DISC, ROW_E_SEG


#: A separating direction must separate by at least this (m): numerical
#: rounding can never turn an overlap into "free".
SEP_EPS = 1e-9


class Chain(NamedTuple):
    """The robot's kinematic chain, bodies in topological order (B of them):
    X_WB = X_WP X_PF X_FM(q) X_MB."""

    parent: np.ndarray  #: (B,) int: the parent body's index, -1 the world
    jtype: np.ndarray  #: (B,) int: 0 weld, 1 revolute, 2 prismatic
    qidx: np.ndarray  #: (B,) int: the joint's position index
    axis: np.ndarray  #: (B, 3): the joint's unit axis in F
    R_PF: np.ndarray  #: (B, 3, 3)
    p_PF: np.ndarray  #: (B, 3)
    R_MB: np.ndarray  #: (B, 3, 3)
    p_MB: np.ndarray  #: (B, 3)


class Model(NamedTuple):
    """The robot and its obstacles as the kernel sees them
    (:meth:`drake_cfvol.scene.arrays.SceneArrays.model`)."""

    chain: Chain
    shapes: np.ndarray  #: (S, SHAPE_W) robot shape rows in their body frames
    shape_body: np.ndarray  #: (S,) int
    verts: np.ndarray  #: (V, 3) hull vertices of every mesh shape (robot and obstacles)
    obstacles: np.ndarray  #: (O, SHAPE_W) obstacle rows in the world
    obstacle_aabb: np.ndarray  #: (O, 6)
    body_pairs: np.ndarray  #: (P, 2) int: robot body pairs Drake does not filter
    shape_pairs: np.ndarray  #: (P', 2) int: robot shape pairs of those body pairs
    movable: np.ndarray  #: (B,) bool: moved by some joint
    moved: np.ndarray  #: (k, B) bool: joint j moves body b
    reach: np.ndarray  #: (k, B): body b's shapes' largest distance from joint j's axis
    curvature: np.ndarray  #: (k, k, B): second-derivative bounds of b's points
    revolute: np.ndarray  #: (k,) bool
    joint_body: np.ndarray  #: (k,) int: the body each joint moves first
    spheres: np.ndarray  #: (N, 4) balls covering the robot shapes: centre in the body frame, radius, m
    shape_spheres: np.ndarray  #: (S, 2) int: shape s's balls are spheres[start:stop]


class Blocks(NamedTuple):
    """What the block kernel (:mod:`drake_cfvol.kernel.blocks`) adds to a
    :class:`Model`, built once per robot
    (:meth:`drake_cfvol.scene.arrays.SceneArrays.blocks`)."""

    KR: np.ndarray  #: (B, 3, 9) each body's rotation in its parent: constant, cos q and sin q terms
    Kp: np.ndarray  #: (B, 3, 3) its translation: constant, cos q and sin q terms (prismatic: constant, q)
    balls: np.ndarray  #: (N, 4) the block check's cover balls: centre in the body frame, radius, m
    ranges: np.ndarray  #: (S, 2) int: shape s's balls are balls[start:stop]
    bounds: np.ndarray  #: (S, 4) a ball around each shape's balls (centre in the body frame, radius), m
    kind: np.ndarray  #: (S,) int: the shape's kind where a ball's distance to it has a closed form, else -1


class HeightField(NamedTuple):
    """The volume V's columns: a range-maximum table and the grid."""

    table: np.ndarray  #: :func:`range_max_table` of the heights; (1, 1, 0, 0): none
    ox: float  #: the grid's corner x, m
    oy: float  #: the grid's corner y, m
    side: float  #: a cell's side, m


class Scratch(NamedTuple):
    """One thread's scratch for the scene tests (:func:`new_scratch`)."""

    ws: np.ndarray
    stack: np.ndarray
    box: np.ndarray
    tmp6: np.ndarray


class RegionScratch(NamedTuple):
    """One thread's scratch for the region tests (:func:`_region_workspace`)."""

    RP: np.ndarray
    pP: np.ndarray
    objs: np.ndarray
    aabbs: np.ndarray
    rel: np.ndarray
    rel_aabb: np.ndarray
    q_c: np.ndarray
    dirs: np.ndarray  #: (S, O + S, 3) each pair's last separating direction (zero: none yet)
    fp: np.ndarray  #: (6,) the union of the boxes tested against the scene (min xyz, max xyz), m
    rowbox: np.ndarray  #: (P, 6) each grid pose's axis-aligned box
    cell: np.ndarray  #: (4, SHAPE_W) one grid cell's corner poses
    cen: np.ndarray  #: (P, 3) one cover ball's centre at each grid pose
    half: np.ndarray  #: (k,) each joint's half range over the region
    balls: np.ndarray  #: (N, 4) the cover balls in the world
    qbox: np.ndarray  #: (6,) a ball's box
    bound: np.ndarray  #: (S, 4) each shape's bounding ball (centre in its body frame, radius)
    local_box: np.ndarray  #: (S, 6) each shape's axis-aligned box in its body's frame (min xyz, max xyz), m
    cover_cen: np.ndarray  #: (Q, P, 3) a shape's cover balls' centres at each grid pose (a self pair's frame)
    cover_r: np.ndarray  #: (Q,) their radii grown by the second-order bound and the margin, m


#: Most poses sampled along t and along v in one region test.
MAX_T_SAMPLES = 5


MAX_V_SAMPLES = 9

#: A search's memo (:func:`~drake_cfvol.kernel.regions.sweep_chains`): at
#: most this many tests kept, each as va, vb, nv, its verdict and its
#: footprint (min xyz, max xyz).
MEMO_T = 48
MEMO_W = 10


#: Directions sampled around a shape for its xy footprint polygon.
FOOTPRINT_DIRECTIONS = 8
