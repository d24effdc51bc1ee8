"""The region test cell by cell: each cell of the nt x nv grid holds the
shape's points in the hull of its four corner poses grown by the
second-order bound (a subset of the whole grid's hull), so a cell whose box
is clear is done and the others go to GJK on four rows instead of all of
them; and cover balls (or a shape's bounding ball) swept over the grid
decide a shape or a self pair before any row is posed.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from drake_cfvol.kernel.checks import _object_vs_scene
from drake_cfvol.kernel.gjk import _gjk_from
from drake_cfvol.kernel.shapes import _aabb_apart, row_aabb_inline
from drake_cfvol.kernel.spheres import ball_apart_row, box_above_columns

__all__ = ["shape_bounds"]


@njit(cache=True, inline="always")
def _corners(ti, t1, vi, nv):
    """The grid indices of cell (ti, vi)'s corners (t1 = the next t row,
    or ti itself on a one-row grid)."""
    v1 = min(vi + 1, nv - 1)
    return ti * nv + vi, ti * nv + v1, t1 * nv + vi, t1 * nv + v1


@njit(cache=True)
def _balls_clear_over_region(s, nt, nv, m, e, field, rs, box):
    """True if every cover ball of shape s, grown by ``e`` (the second-order
    bound and the margin), stays clear of the scene over the region: the
    box of its centres over the whole grid, else over each cell of it (a
    shape's point lies in the hull of its four corner positions grown by
    the bound, each in its ball). Adds every ball's whole box to the
    footprint (it contains the shape's boxes). False: undecided."""
    b = m.shape_body[s]
    spheres, obs_aabb = m.spheres, m.obstacle_aabb
    RP, pP, cen, fp = rs.RP, rs.pP, rs.cen, rs.fp
    P = nt * nv
    clear = True
    for q in range(m.shape_spheres[s, 0], m.shape_spheres[s, 1]):
        x0 = spheres[q, 0]
        x1 = spheres[q, 1]
        x2 = spheres[q, 2]
        r = spheres[q, 3] + e
        for a in range(3):
            box[a] = np.inf
            box[a + 3] = -np.inf
        for c in range(P):
            for a in range(3):
                v = pP[c, b, a] + RP[c, b, a, 0] * x0 + RP[c, b, a, 1] * x1 + RP[c, b, a, 2] * x2
                cen[c, a] = v
                box[a] = min(box[a], v - r)
                box[a + 3] = max(box[a + 3], v + r)
        for a in range(3):
            fp[a] = min(fp[a], box[a])
            fp[a + 3] = max(fp[a + 3], box[a + 3])
        if not clear or _scene_clear_of_box(box, obs_aabb, field):
            continue
        for ti in range(max(nt - 1, 1)):
            t1 = min(ti + 1, nt - 1)
            for vi in range(max(nv - 1, 1)):
                c00, c01, c10, c11 = _corners(ti, t1, vi, nv)
                for a in range(3):
                    box[a] = min(min(cen[c00, a], cen[c01, a]), min(cen[c10, a], cen[c11, a])) - r
                    box[a + 3] = max(max(cen[c00, a], cen[c01, a]), max(cen[c10, a], cen[c11, a])) + r
                if not _scene_clear_of_box(box, obs_aabb, field):
                    clear = False
                    break
            if not clear:
                break
    return clear


@njit(cache=True)
def _row_boxes(obj, verts, rowbox, box):
    """Each row's axis-aligned box into rowbox, their union into box."""
    for c in range(obj.shape[0]):
        row_aabb_inline(obj[c], verts, rowbox[c])
        for r in range(3):
            if c == 0 or rowbox[c, r] < box[r]:
                box[r] = rowbox[c, r]
            if c == 0 or rowbox[c, r + 3] > box[r + 3]:
                box[r + 3] = rowbox[c, r + 3]


@njit(cache=True)
def _scene_clear_of_box(box, obs_aabb, field):
    """True if the box meets no obstacle's axis-aligned box and stands
    above every column of V under it."""
    for o in range(obs_aabb.shape[0]):
        if not _aabb_apart(box, obs_aabb[o]):
            return False
    return box_above_columns(box, field)


@njit(cache=True)
def _cells_vs_scene(obj, nt, nv, rs, m, field, sc, dirs):
    """The shape over the region, cell by cell of the nt x nv grid: in each
    cell its points lie in the hull of the cell's four corner poses grown
    by the same second-order bound (along t at each v, then along v), a
    subset of the whole grid's hull. A cell whose box is clear of the scene
    is done; the others go to the exact test of their four rows."""
    cell, rowbox = rs.cell, rs.rowbox
    box = sc.tmp6
    for ti in range(max(nt - 1, 1)):
        t1 = min(ti + 1, nt - 1)
        for vi in range(max(nv - 1, 1)):
            c00, c01, c10, c11 = _corners(ti, t1, vi, nv)
            _cell_box(rowbox, c00, c01, c10, c11, box)
            if _scene_clear_of_box(box, m.obstacle_aabb, field):
                continue
            _cell_rows(obj, c00, c01, c10, c11, cell)
            if _object_vs_scene(cell, box, m, field, sc, dirs):
                return True
    return False


@njit(cache=True)
def _ball_box_in_frame(rs, P, f, mb, ball, e, box):
    """The box, in body f's frame, of a ball of body mb (centre in mb's
    frame, radius; grown by ``e``) over the region's P grid poses."""
    RP, pP = rs.RP, rs.pP
    r = ball[3] + e
    for a in range(3):
        box[a] = np.inf
        box[a + 3] = -np.inf
    for c in range(P):
        d0 = pP[c, mb, 0] - pP[c, f, 0]
        d1 = pP[c, mb, 1] - pP[c, f, 1]
        d2 = pP[c, mb, 2] - pP[c, f, 2]
        w0 = d0 + RP[c, mb, 0, 0] * ball[0] + RP[c, mb, 0, 1] * ball[1] + RP[c, mb, 0, 2] * ball[2]
        w1 = d1 + RP[c, mb, 1, 0] * ball[0] + RP[c, mb, 1, 1] * ball[1] + RP[c, mb, 1, 2] * ball[2]
        w2 = d2 + RP[c, mb, 2, 0] * ball[0] + RP[c, mb, 2, 1] * ball[1] + RP[c, mb, 2, 2] * ball[2]
        for a in range(3):  # ... in f's frame
            x = RP[c, f, 0, a] * w0 + RP[c, f, 1, a] * w1 + RP[c, f, 2, a] * w2
            box[a] = min(box[a], x - r)
            box[a + 3] = max(box[a + 3], x + r)


@njit(cache=True)
def shape_bounds(spheres, ranges, out):
    """Each shape's bounding ball (centre in its body frame, radius) from its
    cover: centred in the cover balls' box, reaching the farthest ball."""
    for s in range(ranges.shape[0]):
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        for q in range(ranges[s, 0], ranges[s, 1]):
            for a in range(3):
                lo[a] = min(lo[a], spheres[q, a])
                hi[a] = max(hi[a], spheres[q, a])
        r = 0.0
        for a in range(3):
            out[s, a] = 0.5 * (lo[a] + hi[a])
        for q in range(ranges[s, 0], ranges[s, 1]):
            d = np.sqrt(
                (spheres[q, 0] - out[s, 0]) ** 2 + (spheres[q, 1] - out[s, 1]) ** 2 + (spheres[q, 2] - out[s, 2]) ** 2
            )
            r = max(r, d + spheres[q, 3])
        out[s, 3] = r


@njit(cache=True, inline="always")
def _cell_box(rowbox, c00, c01, c10, c11, box):
    """The union of a cell's four corner rows' boxes into ``box``."""
    for r in range(3):
        box[r] = min(min(rowbox[c00, r], rowbox[c01, r]), min(rowbox[c10, r], rowbox[c11, r]))
        box[r + 3] = max(max(rowbox[c00, r + 3], rowbox[c01, r + 3]), max(rowbox[c10, r + 3], rowbox[c11, r + 3]))


@njit(cache=True, inline="always")
def _cell_rows(obj, c00, c01, c10, c11, cell):
    """A cell's four corner rows of ``obj`` into ``cell`` (4, SHAPE_W)."""
    cell[0] = obj[c00]
    cell[1] = obj[c01]
    cell[2] = obj[c10]
    cell[3] = obj[c11]


@njit(cache=True, inline="always")
def _cell_balls_apart(cen, radii, nq, c00, c01, c10, c11, row, row_box):
    """Whether every cover ball of a shape stays apart from ``row`` over a
    grid cell (:func:`ball_apart_row`; ``row_box`` its axis-aligned box):
    ball q's centre is at cen[q, c] at the cell's corner c, its radius
    radii[q] (the second-order bound and the margin included). A
    point of the shape in ball q lies, over the cell, in the hull of its
    four corner positions grown by the bound, each in ball q at its corner:
    within radii[q] + rho of the corners' mean, rho the farthest corner."""
    for q in range(nq):
        m0 = 0.25 * (cen[q, c00, 0] + cen[q, c01, 0] + cen[q, c10, 0] + cen[q, c11, 0])
        m1 = 0.25 * (cen[q, c00, 1] + cen[q, c01, 1] + cen[q, c10, 1] + cen[q, c11, 1])
        m2 = 0.25 * (cen[q, c00, 2] + cen[q, c01, 2] + cen[q, c10, 2] + cen[q, c11, 2])
        rho2 = 0.0
        for c in (c00, c01, c10, c11):
            d0 = cen[q, c, 0] - m0
            d1 = cen[q, c, 1] - m1
            d2 = cen[q, c, 2] - m2
            rho2 = max(rho2, d0 * d0 + d1 * d1 + d2 * d2)
        if not ball_apart_row(m0, m1, m2, radii[q] + np.sqrt(rho2), row, row_box):
            return False
    return True


@njit(cache=True)
def _cells_hit_row(obj, nt, nv, rs, row, row_box, verts, ws, dirs, nq):
    """The grid object ``obj`` (nt x nv rows, their boxes in rs.rowbox)
    against one shape row ((1, SHAPE_W); its box ``row_box``), cell by cell as in
    :func:`_cells_vs_scene`: a cell whose box misses the row's is done, then
    one whose ``nq`` cover balls (rs.cover_cen, rs.cover_r) all stay apart
    from the row (:func:`_cell_balls_apart`; none: skipped); the others go
    to GJK on their four rows."""
    cell, rowbox = rs.cell, rs.rowbox
    for ti in range(max(nt - 1, 1)):
        t1 = min(ti + 1, nt - 1)
        for vi in range(max(nv - 1, 1)):
            c00, c01, c10, c11 = _corners(ti, t1, vi, nv)
            _cell_box(rowbox, c00, c01, c10, c11, rs.qbox)
            if _aabb_apart(rs.qbox, row_box):
                continue
            if nq > 0 and _cell_balls_apart(rs.cover_cen, rs.cover_r, nq, c00, c01, c10, c11, row[0], row_box):
                continue
            _cell_rows(obj, c00, c01, c10, c11, cell)
            if _gjk_from(cell, verts, row, verts, 64, ws, dirs):
                return True
    return False
