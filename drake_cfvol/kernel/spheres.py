"""The broad phase on sphere covers: balls that contain the robot's shapes
(:mod:`drake_cfvol.scene.covers`, checked when built) against obstacle rows,
the height field and each other. Each test answers "certainly apart" or
"undecided"; an undecided pair goes to the exact test.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from drake_cfvol.kernel.heightfield import range_max
from drake_cfvol.kernel.kinds import box as _box
from drake_cfvol.kernel.kinds import capsule as _capsule
from drake_cfvol.kernel.kinds import cylinder as _cylinder
from drake_cfvol.kernel.kinds import sphere as _sphere
from drake_cfvol.kernel.types import _C, _ED, _EI, _ES, _K, _R, _S, BOX, CAPSULE, CYLINDER, SEP_EPS, SPHERE

__all__ = ["ball_apart_row", "box_above_columns", "place_balls"]


@njit(cache=True, inline="always")
def ball_apart_row(x, y, z, r, row, aabb):
    """True if the ball (centre x, y, z; radius r, m) is farther than
    SEP_EPS from a shape row (its inflation and motion terms added to r):
    exact for a kind with a closed form (a box, sphere, capsule or
    cylinder: the centre's offset from the kind's core), against the row's
    axis-aligned box ``aabb`` otherwise."""
    kind = int(row[_K])
    if kind == BOX or kind == SPHERE or kind == CAPSULE or kind == CYLINDER:
        s0 = row[_S]
        s1 = row[_S + 1]
        s2 = row[_S + 2]
        dx = x - row[_C]
        dy = y - row[_C + 1]
        dz = z - row[_C + 2]
        l0 = row[_R + 0] * dx + row[_R + 3] * dy + row[_R + 6] * dz
        l1 = row[_R + 1] * dx + row[_R + 4] * dy + row[_R + 7] * dz
        l2 = row[_R + 2] * dx + row[_R + 5] * dy + row[_R + 8] * dz
        if kind == BOX:  # the kind modules' excess over their cores (drake_cfvol.kernel.kinds)
            core = _box.core_radius(s0, s1, s2)
            l0, l1, l2 = _box.excess(l0, l1, l2, s0, s1, s2)
        elif kind == SPHERE:
            core = _sphere.core_radius(s0, s1, s2)
            l0, l1, l2 = _sphere.excess(l0, l1, l2, s0, s1, s2)
        elif kind == CAPSULE:
            core = _capsule.core_radius(s0, s1, s2)
            l0, l1, l2 = _capsule.excess(l0, l1, l2, s0, s1, s2)
        else:
            core = _cylinder.core_radius(s0, s1, s2)
            l0, l1, l2 = _cylinder.excess(l0, l1, l2, s0, s1, s2)
        rr = r + core + row[_EI] + row[_ED] + row[_ES] + SEP_EPS
        return l0 * l0 + l1 * l1 + l2 * l2 > rr * rr
    d2 = 0.0
    ex = max(aabb[0] - x, x - aabb[3])
    ey = max(aabb[1] - y, y - aabb[4])
    ez = max(aabb[2] - z, z - aabb[5])
    if ex > 0.0:
        d2 += ex * ex
    if ey > 0.0:
        d2 += ey * ey
    if ez > 0.0:
        d2 += ez * ez
    rr = r + SEP_EPS
    return d2 > rr * rr


@njit(cache=True, inline="always")
def box_above_columns(box, field):
    """True if an axis-aligned box (min xyz, max xyz) is certainly clear of
    the height field's columns: the tallest column under its footprint is
    lower than its bottom (an empty table: no columns)."""
    table, ox, oy, side = field
    if table.shape[2] == 0:
        return True
    top = range_max(
        table,
        int(np.floor((box[0] - ox) / side)),
        int(np.floor((box[3] - ox) / side)),
        int(np.floor((box[1] - oy) / side)),
        int(np.floor((box[4] - oy) / side)),
    )
    return not (top > 0.0) or box[2] > top + SEP_EPS


@njit(cache=True)
def place_balls(R_WB, p_WB, shape_body, spheres, ranges, pad, balls, box):
    """Every cover ball (``spheres`` (N, 4) in body frames, shape s's rows
    ``ranges[s]``) in the world at body poses X_WB, radius grown by
    ``pad``: balls (N, 4); box (S, 6) each shape's balls' axis-aligned box."""
    for s in range(ranges.shape[0]):
        b = shape_body[s]
        for a in range(3):
            box[s, a] = np.inf
            box[s, 3 + a] = -np.inf
        for q in range(ranges[s, 0], ranges[s, 1]):
            c0 = spheres[q, 0]
            c1 = spheres[q, 1]
            c2 = spheres[q, 2]
            r = spheres[q, 3] + pad
            balls[q, 3] = r
            for a in range(3):
                v = p_WB[b, a] + R_WB[b, a, 0] * c0 + R_WB[b, a, 1] * c1 + R_WB[b, a, 2] * c2
                balls[q, a] = v
                if v - r < box[s, a]:
                    box[s, a] = v - r
                if v + r > box[s, 3 + a]:
                    box[s, 3 + a] = v + r
