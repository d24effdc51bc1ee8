"""Meshcat drawing: the volume V, the obstacles coloured by category and the
nominal tool path (colours from :mod:`drake_cfvol.io.style`)."""

from __future__ import annotations

import numpy as np
from pydrake.geometry import Rgba, SurfaceTriangle, TriangleSurfaceMesh

from drake_cfvol.algorithm.heightmap import Volume
from drake_cfvol.algorithm.planning import NominalPath
from drake_cfvol.io.style import CATEGORY_COLOURS, PATH_COLOUR, VOLUME_COLOUR
from drake_cfvol.algorithm.volume import VolumeBuild, ground_obstacles

__all__ = ["volume_mesh", "show_volume", "show_tool_path"]


def volume_mesh(volume: Volume) -> TriangleSurfaceMesh | None:
    """All columns of V as one ``TriangleSurfaceMesh`` (12 triangles per
    column), for Meshcat: one object instead of thousands."""
    centres, sizes = volume.boxes()
    if not len(centres):
        return None
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    faces = np.array([(0, 2, 3), (0, 3, 1), (4, 5, 7), (4, 7, 6), (0, 1, 5), (0, 5, 4),
                      (2, 6, 7), (2, 7, 3), (0, 4, 6), (0, 6, 2), (1, 3, 7), (1, 7, 5)])
    verts = (centres[:, None, :] + signs[None] * sizes[:, None, :] / 2).reshape(-1, 3)
    tris = (faces[None] + 8 * np.arange(len(centres))[:, None, None]).reshape(-1, 3)
    return TriangleSurfaceMesh([SurfaceTriangle(*t) for t in tris.tolist()], verts)


def show_tool_path(meshcat, workcell, path: NominalPath, *, name: str = "/cfvol/nominal_tool_path") -> None:
    """Draws the nominal tool path p_WT(s) as a line."""
    p_WT = np.array([workcell.tool_position(q) for q in path.waypoints]).T
    meshcat.SetLine(name, p_WT, 4.0, Rgba(*PATH_COLOUR))


def show_volume(meshcat, workcell, build: VolumeBuild, path: NominalPath | None = None, *,
                prefix: str = "/cfvol") -> None:
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
        workcell.scene_graph.GetMyContextFromRoot(workcell.context))
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
