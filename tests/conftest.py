"""Shared fixtures: the built-in cells (loaded once) and small hand-made cells
whose geometry can be worked out by hand."""

from __future__ import annotations

import struct
import textwrap
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import settings

import drake_cfvol as cf

# Property tests draw their examples from a fixed seed (each test's own,
# hypothesis's derandomize), so a run is reproducible.
settings.register_profile("deterministic", derandomize=True)
settings.load_profile("deterministic")


@pytest.fixture(scope="session", autouse=True)
def certificate_cache(tmp_path_factory):
    """Certificates computed by the tests go to a cache of the session's own
    (never the user's ~/.cache), shared by the tests of one run."""
    import os

    folder = tmp_path_factory.mktemp("cfvol_cache")
    old = os.environ.get("DRAKE_CFVOL_CACHE")
    os.environ["DRAKE_CFVOL_CACHE"] = str(folder)
    yield folder
    if old is None:
        os.environ.pop("DRAKE_CFVOL_CACHE", None)
    else:
        os.environ["DRAKE_CFVOL_CACHE"] = old


@pytest.fixture(scope="session")
def automotive():
    return cf.load_workcell("automotive")


@pytest.fixture(scope="session")
def aerospace():
    return cf.load_workcell("aerospace")


@pytest.fixture(scope="session")
def planned(automotive, aerospace):
    """planned(cell, label, seed) -> NominalPath, planned once per session
    (planning is deterministic per seed, so sharing changes nothing)."""
    cells = {"automotive": automotive, "aerospace": aerospace}
    cache: dict = {}

    def get(cell: str, label: str = "path1", seed: int = 0):
        key = (cell, label, seed)
        if key not in cache:
            wc = cells[cell]
            cache[key] = cf.plan_nominal_path(wc, *wc.configuration(label), seed=seed, label=label)
        return cache[key]

    return get


@pytest.fixture(scope="session")
def bounded(automotive, aerospace, planned):
    """bounded(cell, label, resolution) -> BoundsTable (seed 0), once per session."""
    cells = {"automotive": automotive, "aerospace": aerospace}
    cache: dict = {}

    def get(cell: str, label: str = "path1", resolution: int = 1000):
        key = (cell, label, resolution)
        if key not in cache:
            cache[key] = cf.estimate_bounds(cells[cell], planned(cell, label), resolution=resolution)
        return cache[key]

    return get


def box_stl_bytes(size, centre=(0, 0, 0)) -> bytes:
    """A binary STL of an axis-aligned box."""
    sx, sy, sz = (s / 2 for s in size)
    cx, cy, cz = centre
    v = np.array([[x, y, z] for x in (-sx, sx) for y in (-sy, sy) for z in (-sz, sz)]) + [cx, cy, cz]
    faces = [
        (0, 1, 3),
        (0, 3, 2),
        (4, 6, 7),
        (4, 7, 5),
        (0, 4, 5),
        (0, 5, 1),
        (2, 3, 7),
        (2, 7, 6),
        (0, 2, 6),
        (0, 6, 4),
        (1, 5, 7),
        (1, 7, 3),
    ]
    out = bytearray(b"\0" * 80) + struct.pack("<I", len(faces))
    for f in faces:
        out += struct.pack("<3f", 0, 0, 0)
        for i in f:
            out += struct.pack("<3f", *v[i])
        out += struct.pack("<H", 0)
    return bytes(out)


def write_arm_cell(
    folder: Path,
    *,
    links: list[dict],
    obstacles: dict[str, tuple],
    configurations: dict | None = None,
    cfvol_extra: dict | None = None,
    base_z: float = 0.5,
    mesh_links: bool = False,
    floor: bool = True,
) -> Path:
    """Writes a planar arm (revolute joints about z) as a ROS-style package,
    its obstacles and a workcell YAML; returns the YAML's path.

    Args:
        links: per link ``{"length": L, "half_width": w, "lower": lo,
            "upper": hi}`` (a box from x = 0 to L, |y| <= w, |z| <= w; the
            next joint at x = L). ``lower``/``upper`` None means no limits
            (a continuous joint).
        obstacles: name -> (size, centre) boxes in the world.
        mesh_links: use STL meshes (in the package) instead of boxes.
    """
    pkg = folder / "toy_description"
    (pkg / "urdf").mkdir(parents=True, exist_ok=True)
    (pkg / "meshes").mkdir(exist_ok=True)
    (pkg / "package.xml").write_text(
        textwrap.dedent("""\
        <?xml version="1.0"?>
        <package format="2"><name>toy_description</name><version>0.0.1</version>
        <description>test arm</description><maintainer email="a@b.c">t</maintainer>
        <license>BSD</license></package>
        """)
    )
    parts = [
        '<?xml version="1.0"?>',
        '<robot name="toy">',
        '<link name="base"><collision><origin xyz="0 0 -0.05"/><geometry><box size="0.2 0.2 0.1"/></geometry></collision></link>',
    ]
    parent = "base"
    x_prev = 0.0
    for i, ln in enumerate(links, start=1):
        L, w = ln["length"], ln["half_width"]
        if mesh_links:
            (pkg / "meshes" / f"link{i}.stl").write_bytes(box_stl_bytes((L, 2 * w, 2 * w), (L / 2, 0, 0)))
            geom = f'<origin xyz="0 0 0"/><geometry><mesh filename="package://toy_description/meshes/link{i}.stl"/></geometry>'
        else:
            geom = f'<origin xyz="{L / 2} 0 0"/><geometry><box size="{L} {2 * w} {2 * w}"/></geometry>'
        parts.append(
            f'<link name="link{i}"><inertial><mass value="1"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial>'
            f"<visual>{geom}</visual><collision>{geom}</collision></link>"
        )
        if ln.get("lower") is None:
            jt, lim = "continuous", '<limit velocity="1" effort="1"/>'
        else:
            jt, lim = "revolute", f'<limit lower="{ln["lower"]}" upper="{ln["upper"]}" velocity="1" effort="1"/>'
        parts.append(
            f'<joint name="joint{i}" type="{jt}"><parent link="{parent}"/><child link="link{i}"/>'
            f'<origin xyz="{x_prev} 0 0"/><axis xyz="0 0 1"/>{lim}</joint>'
        )
        parent, x_prev = f"link{i}", L
    parts.append(
        f'<link name="tool"/><joint name="tool_joint" type="fixed"><parent link="{parent}"/>'
        f'<child link="tool"/><origin xyz="{x_prev} 0 0"/></joint>'
    )
    parts.append("</robot>")
    (pkg / "urdf" / "toy.urdf").write_text("\n".join(parts))

    obs = dict(obstacles)
    if floor:
        obs.setdefault("floor", ((10.0, 10.0, 0.1), (0.0, 0.0, -0.05)))
    sdf = ['<?xml version="1.0"?><sdf version="1.9"><model name="scene"><static>true</static>']
    for name, (size, centre) in obs.items():
        s = " ".join(map(str, size))
        sdf.append(
            f'<link name="{name}"><pose>{" ".join(map(str, centre))} 0 0 0</pose>'
            f'<collision name="c"><geometry><box><size>{s}</size></box></geometry></collision></link>'
        )
    sdf.append("</model></sdf>")
    (folder / "scene.sdf").write_text("\n".join(sdf))
    cfvol = {
        "robot": "toy",
        "tool_frame": "tool",
        "base_frame": "base",
        "reach": 3.0,
        "package_paths": {"toy_description": "toy_description"},
        "height_map": {"origin": [-3.0, -3.0], "size": [6.0, 6.0]},
        "configurations": configurations or {},
    }
    cfvol.update(cfvol_extra or {})
    doc = {
        "directives": [
            {"add_model": {"name": "toy", "file": "package://toy_description/urdf/toy.urdf"}},
            {"add_weld": {"parent": "world", "child": "toy::base", "X_PC": {"translation": [0.0, 0.0, base_z]}}},
            {"add_model": {"name": "scene", "file": "scene.sdf"}},
        ],
        "cfvol": cfvol,
    }
    path = folder / "toy_cell.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path
