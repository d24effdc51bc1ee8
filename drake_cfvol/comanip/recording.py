"""Meshcat drawing: the volume V, the obstacles coloured by category and the
nominal tool path (colours from :mod:`drake_cfvol.io.style`)."""

from __future__ import annotations

import numpy as np
from pydrake.geometry import Rgba, SurfaceTriangle, TriangleSurfaceMesh

from drake_cfvol.algorithm.heightmap import Volume
from drake_cfvol.algorithm.planning import NominalPath
from drake_cfvol.algorithm.volume import VolumeBuild, ground_obstacles
from drake_cfvol.io.style import CATEGORY_COLOURS, PATH_COLOUR, VOLUME_COLOUR

__all__ = ["volume_mesh", "show_volume", "show_tool_path", "animate_freedom", "animate_columns"]


def volume_mesh(volume: Volume) -> TriangleSurfaceMesh | None:
    """All columns of V as one ``TriangleSurfaceMesh`` (12 triangles per
    column), for Meshcat: one object instead of thousands."""
    centres, sizes = volume.boxes()
    if not len(centres):
        return None
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    faces = np.array(
        [
            (0, 2, 3),
            (0, 3, 1),
            (4, 5, 7),
            (4, 7, 6),
            (0, 1, 5),
            (0, 5, 4),
            (2, 6, 7),
            (2, 7, 3),
            (0, 4, 6),
            (0, 6, 2),
            (1, 3, 7),
            (1, 7, 5),
        ]
    )
    verts = (centres[:, None, :] + signs[None] * sizes[:, None, :] / 2).reshape(-1, 3)
    tris = (faces[None] + 8 * np.arange(len(centres))[:, None, None]).reshape(-1, 3)
    return TriangleSurfaceMesh([SurfaceTriangle(*t) for t in tris.tolist()], verts)


def show_tool_path(meshcat, workcell, path: NominalPath, *, name: str = "/cfvol/nominal_tool_path") -> None:
    """Draws the nominal tool path p_WT(s) as a line."""
    p_WT = np.array([workcell.tool_position(q) for q in path.waypoints]).T
    meshcat.SetLine(name, p_WT, 4.0, Rgba(*PATH_COLOUR))


def show_volume(
    meshcat, workcell, build: VolumeBuild, path: NominalPath | None = None, *, prefix: str = "/cfvol"
) -> None:
    """Draws the volume (semi-transparent), the obstacles coloured by category
    and, if given, the nominal tool path in a Meshcat.

    Args:
        meshcat: a ``pydrake.geometry.Meshcat``.
        workcell: the workcell.
        build: what :func:`drake_cfvol.algorithm.volume.build_volume` returned (the
            ``volume`` field of a bounds table).
        path: the nominal path (its tool path is drawn as a line).
    """
    mesh = volume_mesh(build.volume)
    if mesh is not None:
        meshcat.SetObject(f"{prefix}/volume", mesh, Rgba(*VOLUME_COLOUR))
    ground = ground_obstacles(workcell)
    inspector = workcell.scene_graph.model_inspector()
    query = workcell.scene_graph.get_query_output_port().Eval(
        workcell.scene_graph.GetMyContextFromRoot(workcell.context)
    )
    for name, obstacle in workcell.obstacles.items():
        if name in ground:
            continue
        category = build.categories.of(name)
        for i, gid in enumerate(obstacle.geometry_ids):
            key = f"{prefix}/obstacles/{category}/{name}_{i}"
            meshcat.SetObject(key, inspector.GetShape(gid), Rgba(*CATEGORY_COLOURS[category]))
            meshcat.SetTransform(key, query.GetPoseInWorld(gid))
    if path is not None:
        show_tool_path(meshcat, workcell, path, name=f"{prefix}/nominal_tool_path")


#: The freedom bars: per joint, a bar 1 m long at the known cell's box width.
FREEDOM_BAR = (1.0, 0.05, 0.05)


def animate_freedom(
    meshcat, times: np.ndarray, ratios: np.ndarray, p_W: np.ndarray, *, prefix: str = "/cfvol/freedom"
) -> None:
    """Adds to Meshcat's recording one bar per joint, stacked at ``p_W``:
    a grey outline 1 m long (the box the known cell allows) and a bar whose
    length follows ``ratios`` (n, k), the live box's width over it at
    ``times`` (n,), s. Call between StopRecording and PublishRecording."""
    from pydrake.geometry import Box
    from pydrake.math import RigidTransform

    anim = meshcat.get_mutable_recording()
    k = ratios.shape[1]
    for j in range(k):
        base = np.asarray(p_W, float) + [0.0, 0.0, 0.12 * j]
        meshcat.SetObject(f"{prefix}/joint_{j + 1}/outline", Box(*FREEDOM_BAR), Rgba(0.6, 0.6, 0.6, 0.3))
        meshcat.SetTransform(f"{prefix}/joint_{j + 1}/outline", RigidTransform(base + [FREEDOM_BAR[0] / 2, 0, 0]))
        meshcat.SetObject(f"{prefix}/joint_{j + 1}/bar", Box(*FREEDOM_BAR), Rgba(1.0, 0.55, 0.0, 0.9))
        last = None
        for t, r in zip(times, np.clip(ratios[:, j], 0.0, 1.0)):
            if last is not None and abs(r - last) < 0.005:
                continue  # a change of under half a percent is not drawn (the file stays small)
            last = r
            frame = anim.frame(float(t))
            path = f"{prefix}/joint_{j + 1}/bar"
            anim.SetProperty(frame, path, "scale", [max(float(r), 1e-3), 1.0, 1.0])
            anim.SetTransform(frame, path, RigidTransform(base + [FREEDOM_BAR[0] * r / 2, 0, 0]))


def animate_columns(
    meshcat, log: tuple, columns, *, prefix: str = "/cfvol/perceived", rgba=(1.0, 0.55, 0.0, 0.35)
) -> None:
    """Adds the perceived columns to Meshcat's recording from
    :meth:`PerceivedColumns.tiles_log`: one object per tile slot used, a
    transform only where a slot changed (shown at its column, or hidden).
    Call between StopRecording and PublishRecording."""
    from pydrake.geometry import Box
    from pydrake.math import RigidTransform

    anim = meshcat.get_mutable_recording()
    g = columns.grid
    shown: dict = {}  # slot -> the pose it shows
    made = set()
    for t, tiles in log:
        frame = anim.frame(float(t))
        used = [0] * columns.levels
        now = {}
        for level, i, j, h in tiles:
            slot = (level, used[level])
            used[level] += 1
            half = 0.5 * g.side * (1 << level)
            now[slot] = (g.origin[0] + i * g.side + half, g.origin[1] + j * g.side + half, h / 2, h)
        for slot in set(now) | set(shown):
            path = f"{prefix}/level_{slot[0]}_{slot[1]}"
            if slot not in made:
                side = g.side * (1 << slot[0])
                meshcat.SetObject(path, Box(side, side, 1.0), Rgba(*rgba))
                made.add(slot)
                if frame > 0:
                    anim.SetProperty(0, path, "visible", False)  # not there before it is first used
            pose = now.get(slot)
            if pose == shown.get(slot):
                continue
            visible = pose is not None
            anim.SetProperty(frame, path, "visible", visible)
            if pose is not None:
                anim.SetTransform(frame, path, RigidTransform(list(pose[:3])))
                anim.SetProperty(frame, path, "scale", [1.0, 1.0, max(pose[3], 1e-3)])
        shown = now
