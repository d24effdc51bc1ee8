"""Writes the robot URDFs in ``models/`` from the numbers in
``shared/reference/robots-and-cells.md``.

One table per robot drives both the visual and the collision geometry, so they
cannot drift apart. Run ``python tools/make_models.py`` after editing a table;
the generated files are committed.

Frames: every link frame sits on its joint axis and is aligned with the world
at the zero configuration (x forward, z up). Lengths in metres, angles in
radians in the files (degrees in the tables below, for reading).
"""

from __future__ import annotations

import math
from pathlib import Path

MODELS = Path(__file__).resolve().parent.parent / "models"

D = math.radians

# Shapes: ("box", (sx, sy, sz), xyz) | ("capsule", r, (x0,y0,z0), (x1,y1,z1))
#       | ("cylinder_x", r, length, xyz)  (cylinder along the link's x axis; _y, _z alike)

# Masses (public datasheets): the IRB 6700-205/2.80 weighs 1170 kg, the KR
# 210 R3100 ultra about 1068 kg; each arm's mass is spread over its links by
# the volume of their collision shapes (one density per robot), the rail's
# carriage at the same density. The gripper is a modelling choice: 100 kg,
# half the payload. Inertias are those of the solid shapes.
ABB_MASS_KG = 1170.0
KUKA_MASS_KG = 1068.0
GRIPPER_MASS_KG = 100.0

ABB = dict(
    name="abb_irb6700",
    mass=ABB_MASS_KG,
    root="base_link",
    colour="0.93 0.45 0.10 1",
    links={
        "base_link": [("box", (1.00, 0.72, 0.37), (-0.125, 0.0, 0.187))],
        "link_1": [("box", (1.08, 0.81, 0.80), (-0.009, -0.049, -0.1645))],
        "link_2": [("capsule", 0.20, (0.0, -0.26, 0.0), (0.0, -0.26, 1.28))],
        "link_3": [("box", (0.52, 0.63, 0.56), (-0.0265, 0.0325, 0.107))],
        # Forearm: starts in front of the lower arm so that link_2 and link_4
        # (not adjacent) are apart at the zero pose; link_3's box covers the
        # housing behind it.
        "link_4": [("capsule", 0.17, (0.43, 0.0, 0.0), (0.98, 0.0, 0.0))],
        "link_5": [("capsule", 0.11, (-0.06, 0.0, 0.0), (0.06, 0.0, 0.0))],
        "link_6": [("cylinder_x", 0.10, 0.041, (-0.0205, 0.0, 0.0))],
        "gripper": [("box", (1.00, 1.70, 0.90), (0.51, 0.0, 0.0))],
    },
    joints=[
        # name, type, parent, child, xyz, axis, lower, upper, vmax
        ("joint_1", "revolute", "base_link", "link_1", (0, 0, 0.780), (0, 0, 1), D(-170), D(170), D(110)),
        ("joint_2", "revolute", "link_1", "link_2", (0.320, 0, 0), (0, 1, 0), D(-65), D(85), D(110)),
        ("joint_3", "revolute", "link_2", "link_3", (0, 0, 1.280), (0, 1, 0), D(-180), D(70), D(110)),
        ("joint_4", "revolute", "link_3", "link_4", (0, 0, 0.200), (1, 0, 0), D(-300), D(300), D(190)),
        ("joint_5", "revolute", "link_4", "link_5", (1.1825, 0, 0), (0, 1, 0), D(-130), D(130), D(150)),
        ("joint_6", "revolute", "link_5", "link_6", (0.200, 0, 0), (1, 0, 0), D(-360), D(360), D(210)),
        ("gripper_mount", "fixed", "link_6", "gripper", (0, 0, 0), None, 0, 0, 0),
        ("tcp_joint", "fixed", "gripper", "tcp", (0.51, 0, 0), None, 0, 0, 0),
    ],
)

KUKA = dict(
    name="kuka_kr210_rail",
    mass=KUKA_MASS_KG,
    unweighed=("rail_base", "carriage"),
    root="rail_base",
    colour="0.95 0.55 0.05 1",
    links={
        # The rail beam (part of the robot model, welded to the world).
        "rail_base": [("box", (11.0, 2.5, 0.40), (0.0, 0.0, 0.20))],
        # Carriage plate (top 0.49 m above the floor) and socket (0.65 m).
        "carriage": [
            ("box", (1.30, 1.30, 0.09), (0.0, 0.0, 0.045)),
            ("box", (1.14, 1.02, 0.65), (0.0, 0.0, 0.415)),
        ],
        "link_1": [("box", (0.63, 1.11, 0.69), (0.10, 0.0, 0.025))],
        # Lower arm lies along the link's +x (A2 = 0 is horizontal).
        "link_2": [("box", (1.71, 0.53, 0.45), (0.675, 0.0, 0.0))],
        # Elbow housing: 0.96 m forward of A3, 0.44 m behind.
        "link_3": [("box", (1.40, 0.53, 0.43), (0.26, 0.0, -0.02))],
        # Forearm tube behind the wrist centre (link_4's frame is the wrist).
        "link_4": [("capsule", 0.125, (-0.495, 0.0, 0.0), (-0.205, 0.0, 0.0))],
        "link_5": [("box", (0.33, 0.34, 0.24), (0.0, 0.0, 0.0))],
        "link_6": [("cylinder_x", 0.10, 0.035, (-0.0175, 0.0, 0.0))],
        "gripper": [("box", (1.00, 1.70, 0.90), (0.51, 0.0, 0.0))],
    },
    joints=[
        ("rail", "prismatic", "rail_base", "carriage", (0, 0, 0.40), (1, 0, 0), -4.0, 4.0, 1.8),
        # A1 about +z (right-hand rule; KUKA's controller counts the other
        # way). A1's frame is 0.675 m above the robot base, which sits 0.385 m
        # above the carriage frame: A2 ends up 1.46 m above the floor.
        ("A1", "revolute", "carriage", "link_1", (0, 0, 1.060), (0, 0, 1), D(-185), D(185), D(105)),
        ("A2", "revolute", "link_1", "link_2", (0.350, 0, 0), (0, 1, 0), D(-140), D(-5), D(101)),
        ("A3", "revolute", "link_2", "link_3", (1.350, 0, 0), (0, 1, 0), D(-120), D(155), D(107)),
        ("A4", "revolute", "link_3", "link_4", (1.400, 0, -0.041), (-1, 0, 0), D(-350), D(350), D(136)),
        ("A5", "revolute", "link_4", "link_5", (0, 0, 0), (0, 1, 0), D(-122.5), D(122.5), D(129)),
        ("A6", "revolute", "link_5", "link_6", (0.240, 0, 0), (-1, 0, 0), D(-350), D(350), D(206)),
        ("gripper_mount", "fixed", "link_6", "gripper", (0, 0, 0), None, 0, 0, 0),
        ("tcp_joint", "fixed", "gripper", "tcp", (0.51, 0, 0), None, 0, 0, 0),
    ],
)


# The torque-sensing cobot: KUKA LBR iiwa 14 R820 (public data sheet: 7
# axes, 29.9 kg, 14 kg payload; axis distances 0.36 / 0.42 / 0.40 / 0.126 m
# from the base to A2, A2 to A4, A4 to A6, A6 to the flange; ranges +-170,
# +-120, +-170, +-120, +-170, +-120, +-175 deg; speeds 85, 85, 100, 75, 130,
# 135, 135 deg/s; torques 320, 320, 176, 176, 110, 40, 40 N m). Joints with
# transmissions, so that Drake's IiwaDriver finds the 7 actuators. A small
# hand-guiding tool on the flange (1.5 kg, a modelling choice).
IIWA_MASS_KG = 29.9
IIWA_TOOL_MASS_KG = 1.5

IIWA = dict(
    name="iiwa14",
    root="iiwa_link_0",
    colour="0.85 0.85 0.88 1",
    mass=IIWA_MASS_KG,
    gripper_mass=IIWA_TOOL_MASS_KG,
    efforts=(320, 320, 176, 176, 110, 40, 40),
    links={
        "iiwa_link_0": [("capsule", 0.105, (0.0, 0.0, 0.05), (0.0, 0.0, 0.06))],
        "iiwa_link_1": [("capsule", 0.08, (0.0, 0.0, 0.0), (0.0, 0.0, 0.14))],
        "iiwa_link_2": [("capsule", 0.08, (0.0, 0.0, 0.03), (0.0, 0.0, 0.17))],
        "iiwa_link_3": [("capsule", 0.075, (0.0, 0.0, 0.0), (0.0, 0.0, 0.15))],
        "iiwa_link_4": [("capsule", 0.075, (0.0, 0.0, 0.03), (0.0, 0.0, 0.13))],
        "iiwa_link_5": [("capsule", 0.07, (0.0, 0.0, 0.0), (0.0, 0.0, 0.14))],
        "iiwa_link_6": [("capsule", 0.065, (0.0, 0.0, 0.0), (0.0, 0.0, 0.02))],
        "iiwa_link_7": [("cylinder_z", 0.045, 0.045, (0.0, 0.0, 0.0225))],
        # A hand-guiding tool: a grip tube along the flange axis.
        "gripper": [("capsule", 0.035, (0.0, 0.0, 0.03), (0.0, 0.0, 0.12))],
    },
    joints=[
        ("iiwa_joint_1", "revolute", "iiwa_link_0", "iiwa_link_1", (0, 0, 0.1575), (0, 0, 1), D(-170), D(170), D(85)),
        ("iiwa_joint_2", "revolute", "iiwa_link_1", "iiwa_link_2", (0, 0, 0.2025), (0, 1, 0), D(-120), D(120), D(85)),
        ("iiwa_joint_3", "revolute", "iiwa_link_2", "iiwa_link_3", (0, 0, 0.2045), (0, 0, 1), D(-170), D(170), D(100)),
        ("iiwa_joint_4", "revolute", "iiwa_link_3", "iiwa_link_4", (0, 0, 0.2155), (0, -1, 0), D(-120), D(120), D(75)),
        ("iiwa_joint_5", "revolute", "iiwa_link_4", "iiwa_link_5", (0, 0, 0.1845), (0, 0, 1), D(-170), D(170), D(130)),
        ("iiwa_joint_6", "revolute", "iiwa_link_5", "iiwa_link_6", (0, 0, 0.2155), (0, 1, 0), D(-120), D(120), D(135)),
        ("iiwa_joint_7", "revolute", "iiwa_link_6", "iiwa_link_7", (0, 0, 0.081), (0, 0, 1), D(-175), D(175), D(135)),
        ("tool_mount", "fixed", "iiwa_link_7", "gripper", (0, 0, 0.045), None, 0, 0, 0),
        ("tcp_joint", "fixed", "gripper", "tcp", (0, 0, 0.14), None, 0, 0, 0),
    ],
)


# The Franka Emika Panda (Franka's robot and interface specification):
# link frames are Franka's modified Denavit-Hartenberg frames (Craig), so the
# joint angles are the robot's own. Joint i's origin in frame i-1 is
# RotX(alpha) TransX(a) TransZ(d) (written below as xyz and an rpy), and every
# joint turns about its z. The arm weighs about 18 kg (17.8 kg, spread by
# volume as above); the Franka Hand 0.73 kg, turned -45 deg about the flange
# as Franka mounts it. Collision shapes: capsules and cylinders of radius
# 0.066-0.07 m around tubes 0.055 m in radius on the robot, boxes around the
# base, link 6, the flange and the hand, sized from the link extents in
# Franka's published description: they hold its collision hulls with 1 cm
# to spare, 3 mm where link 6 and the hand face each other 3 cm apart (so
# that links one joint apart stay more than 2 cm apart, as the runtime
# filter's margin needs: 2.4-4.3 cm here). Flat tube ends are cylinders:
# a capsule's cap would reach 7 cm past them.
PANDA_MASS_KG = 17.8
PANDA_HAND_MASS_KG = 0.73
PANDA_R = 0.07
P2 = math.pi / 2

PANDA = dict(
    name="panda",
    root="panda_link0",
    colour="0.93 0.93 0.93 1",
    mass=PANDA_MASS_KG,
    gripper_mass=PANDA_HAND_MASS_KG,
    efforts=(87, 87, 87, 87, 12, 12, 12),
    accelerations=(15, 7.5, 10, 12.5, 15, 20, 20),
    # The flange (link 7) turns 0.088 m off joint 6's axis, beside the wrist
    # housing of link 5: their real hulls pass within a few millimetres at
    # every angle of joint 6 (link 6 holds them apart), so two covers with a
    # margin would always touch. The hand against link 5 stays checked.
    unchecked_pairs=[("panda_link5", "panda_link7")],
    links={
        "panda_link0": [("box", (0.26, 0.23, 0.18), (-0.04, 0.0, 0.07))],
        "panda_link1": [
            ("capsule", PANDA_R, (0.0, 0.0, -0.19), (0.0, 0.0, 0.0)),
            ("capsule", PANDA_R, (0.0, -0.08, 0.0), (0.0, 0.0, 0.0)),
        ],
        "panda_link2": [
            ("cylinder_y", 0.066, 0.204, (0.0, -0.102, 0.0)),
            ("capsule", PANDA_R, (0.0, 0.0, 0.0), (0.0, 0.0, 0.075)),
        ],
        "panda_link3": [
            ("capsule", PANDA_R, (0.0, 0.0, -0.12), (0.0, 0.0, 0.0)),
            ("capsule", PANDA_R, (0.0, 0.0, 0.0), (0.0825, 0.0, 0.0)),
            ("capsule", PANDA_R, (0.0825, 0.0, 0.0), (0.0825, 0.06, 0.0)),
        ],
        "panda_link4": [
            ("capsule", PANDA_R, (0.0, 0.0, 0.0), (-0.0825, 0.0, 0.0)),
            ("capsule", PANDA_R, (0.0, 0.0, 0.0), (0.0, 0.0, 0.06)),
            ("capsule", PANDA_R, (-0.0825, 0.0, 0.0), (-0.0825, 0.12, 0.0)),
            # Along the elbow-wrist line, which runs by the casing's edge.
            ("capsule", 0.06, (0.0, 0.0, 0.0), (-0.04125, 0.192, 0.0)),
        ],
        # The forearm, its rib and the wrist housing.
        "panda_link5": [
            ("cylinder_z", 0.066, 0.275, (0.0, 0.0, -0.1375)),
            ("capsule", 0.06, (0.0, 0.075, -0.23), (0.0, 0.075, -0.03)),
            ("cylinder_y", 0.062, 0.134, (0.0, 0.073, 0.0)),
        ],
        "panda_link6": [("box", (0.208, 0.15, 0.128), (0.042, 0.021, 0.006))],
        "panda_link7": [("box", (0.15, 0.15, 0.09), (0.02, 0.02, 0.075))],
        # The Franka Hand (frame turned -45 deg from the flange's): the hand
        # and its two fingers, open (to 0.08 m between them).
        "gripper": [
            ("box", (0.09, 0.235, 0.109), (0.0, 0.0, 0.0255)),
            ("box", (0.05, 0.16, 0.08), (0.0, 0.0, 0.085)),
        ],
    },
    joint_rpy={
        "panda_joint2": (-P2, 0, 0),
        "panda_joint3": (P2, 0, 0),
        "panda_joint4": (P2, 0, 0),
        "panda_joint5": (-P2, 0, 0),
        "panda_joint6": (P2, 0, 0),
        "panda_joint7": (P2, 0, 0),
        "tool_mount": (0, 0, -math.pi / 4),
    },
    joints=[
        # Origins (a, -d sin(alpha), d cos(alpha)) from the DH table.
        ("panda_joint1", "revolute", "panda_link0", "panda_link1", (0, 0, 0.333), (0, 0, 1), -2.8973, 2.8973, 2.1750),
        ("panda_joint2", "revolute", "panda_link1", "panda_link2", (0, 0, 0), (0, 0, 1), -1.7628, 1.7628, 2.1750),
        ("panda_joint3", "revolute", "panda_link2", "panda_link3", (0, -0.316, 0), (0, 0, 1), -2.8973, 2.8973, 2.1750),
        ("panda_joint4", "revolute", "panda_link3", "panda_link4", (0.0825, 0, 0), (0, 0, 1), -3.0718, -0.0698, 2.1750),
        (
            "panda_joint5",
            "revolute",
            "panda_link4",
            "panda_link5",
            (-0.0825, 0.384, 0),
            (0, 0, 1),
            -2.8973,
            2.8973,
            2.6100,
        ),
        ("panda_joint6", "revolute", "panda_link5", "panda_link6", (0, 0, 0), (0, 0, 1), -0.0175, 3.7525, 2.6100),
        ("panda_joint7", "revolute", "panda_link6", "panda_link7", (0.088, 0, 0), (0, 0, 1), -2.8973, 2.8973, 2.6100),
        ("flange_joint", "fixed", "panda_link7", "flange", (0, 0, 0.107), None, 0, 0, 0),
        ("tool_mount", "fixed", "flange", "gripper", (0, 0, 0), None, 0, 0, 0),
        # Franka's default TCP with its hand: 0.1034 m out from the flange.
        ("tcp_joint", "fixed", "gripper", "tcp", (0, 0, 0.1034), None, 0, 0, 0),
    ],
)

# Workcells: static SDF models, one named body per obstacle (box size, centre
# in the world). The robot bases: ABB on a 0.42 m pedestal at the origin; the
# KUKA's rail centred on the origin along x.
AUTOMOTIVE = dict(
    name="automotive_cell",
    obstacles={
        "floor": ((12.0, 12.0, 0.10), (0.5, 0.0, -0.05)),
        "pedestal": ((1.00, 0.80, 0.41), (-0.125, 0.0, 0.205)),
        "pick_table": ((1.30, 2.50, 0.90), (0.95, 2.35, 0.45)),
        "mould_stand": ((1.20, 0.80, 0.85), (1.0, -1.95, 0.425)),
        "mould": ((1.50, 1.00, 0.30), (1.0, -1.95, 1.00)),
        "cabinet": ((0.80, 1.20, 1.80), (2.70, 0.0, 0.90)),
        "column": ((0.50, 0.50, 2.20), (-2.0, -2.6, 1.10)),
        "fence_back": ((0.05, 8.0, 2.20), (-3.0, 0.0, 1.10)),
        "fence_front": ((0.05, 8.0, 2.20), (4.2, 0.0, 1.10)),
        "fence_left": ((7.2, 0.05, 2.20), (0.6, 4.0, 1.10)),
        "fence_right": ((7.2, 0.05, 2.20), (0.6, -4.0, 1.10)),
    },
)

AEROSPACE = dict(
    name="aerospace_cell",
    obstacles={
        "floor": ((16.0, 14.0, 0.10), (0.0, 2.0, -0.05)),
        "ply_pallet": ((2.80, 1.60, 0.95), (-3.6, 2.7, 0.475)),
        "mould_stand": ((1.80, 1.20, 0.65), (-0.4, 2.7, 0.325)),
        "mould": ((2.20, 1.60, 0.40), (-0.4, 2.7, 0.85)),
        "jig": ((4.60, 1.40, 1.10), (3.4, 1.8, 0.55)),
        "fence_back": ((11.9, 0.05, 2.20), (0.0, -3.0, 1.10)),
        "fence_front": ((11.9, 0.05, 2.20), (0.0, 7.3, 1.10)),
        "fence_left": ((0.05, 10.3, 2.20), (-5.95, 2.15, 1.10)),
        "fence_right": ((0.05, 10.3, 2.20), (5.95, 2.15, 1.10)),
    },
)

# The cobot cell: the iiwa on a work table (top 0.80 m), a part fixture and
# a screwing fixture on the table, a parts bin beside it, a monitor post and
# a shelf behind. The robot's base sits on the table top at the origin.
COBOT = dict(
    name="cobot_cell",
    obstacles={
        "floor": ((6.0, 6.0, 0.10), (0.0, 0.0, -0.05)),
        "table": ((1.60, 1.20, 0.80), (0.30, 0.0, 0.40)),
        "part_fixture": ((0.30, 0.30, 0.12), (0.62, 0.38, 0.86)),
        "screw_fixture": ((0.26, 0.34, 0.20), (0.62, -0.38, 0.90)),
        "bin": ((0.40, 0.30, 0.25), (-0.30, -0.45, 0.925)),
        "monitor_post": ((0.08, 0.08, 0.70), (-0.35, 0.45, 1.15)),
        "shelf": ((0.30, 1.20, 1.60), (-0.85, 0.0, 0.80)),
    },
)

# The Franka cell: the Panda on a work table (top 0.80 m, base at the
# origin), an open shelf (one board) on the table at its left, a part
# fixture in front, a parts tray (with parts in it) at its right front and
# a camera post behind. Shelf and tray are open boxes of thin panels.
FRANKA = dict(
    name="franka_cell",
    obstacles={
        "floor": ((6.0, 6.0, 0.10), (0.0, 0.0, -0.05)),
        "table": ((1.40, 1.50, 0.80), (0.25, 0.0, 0.40)),
        "shelf_left": ((0.02, 0.28, 0.54), (0.06, 0.50, 1.07)),
        "shelf_right": ((0.02, 0.28, 0.54), (0.54, 0.50, 1.07)),
        "shelf_back": ((0.50, 0.02, 0.54), (0.30, 0.65, 1.07)),
        "shelf_board": ((0.46, 0.28, 0.02), (0.30, 0.50, 1.00)),
        "fixture": ((0.20, 0.20, 0.14), (0.55, 0.05, 0.87)),
        "tray_floor": ((0.34, 0.26, 0.02), (0.45, -0.42, 0.81)),
        "tray_front": ((0.02, 0.26, 0.07), (0.63, -0.42, 0.835)),
        "tray_back": ((0.02, 0.26, 0.07), (0.27, -0.42, 0.835)),
        "tray_left": ((0.38, 0.02, 0.07), (0.45, -0.28, 0.835)),
        "tray_right": ((0.38, 0.02, 0.07), (0.45, -0.56, 0.835)),
        "tray_part_1": ((0.06, 0.05, 0.04), (0.34, -0.36, 0.84)),
        "tray_part_2": ((0.08, 0.04, 0.05), (0.54, -0.50, 0.845)),
        "camera_post": ((0.06, 0.06, 0.90), (-0.40, -0.55, 1.25)),
    },
)

OBSTACLE_COLOURS = {"floor": "0.55 0.55 0.52 1"}


def write_cell_sdf(cell: dict) -> str:
    lines = [
        '<?xml version="1.0"?>',
        "<!-- Generated by tools/make_models.py; do not edit. -->",
        '<sdf version="1.9">',
        f'  <model name="{cell["name"]}">',
        "    <static>true</static>",
    ]
    for name, (size, centre) in cell["obstacles"].items():
        rgba = OBSTACLE_COLOURS.get(name, "0.60 0.70 0.80 1")
        if name.startswith("fence"):
            rgba = "0.90 0.85 0.20 0.35"
        lines += [
            f'    <link name="{name}">',
            f"      <pose>{_f(centre)} 0 0 0</pose>",
            f'      <collision name="{name}_collision"><geometry><box><size>{_f(size)}</size></box></geometry></collision>',
            f'      <visual name="{name}_visual"><geometry><box><size>{_f(size)}</size></box></geometry>'
            f"<material><diffuse>{rgba}</diffuse></material></visual>",
            "    </link>",
        ]
    lines += ["  </model>", "</sdf>"]
    return "\n".join(lines) + "\n"


def _f(v) -> str:
    return " ".join(f"{x:.6g}" for x in v)


def _geometry(shape) -> tuple[str, str]:
    """Returns (origin element, geometry element) for a shape."""
    kind = shape[0]
    if kind == "box":
        _, size, xyz = shape
        return f'<origin xyz="{_f(xyz)}" rpy="0 0 0"/>', f'<box size="{_f(size)}"/>'
    if kind == "cylinder_x":
        _, r, length, xyz = shape
        return (
            f'<origin xyz="{_f(xyz)}" rpy="0 {math.pi / 2:.9f} 0"/>',
            f'<cylinder radius="{r:g}" length="{length:g}"/>',
        )
    if kind == "cylinder_z":
        _, r, length, xyz = shape
        return f'<origin xyz="{_f(xyz)}" rpy="0 0 0"/>', f'<cylinder radius="{r:g}" length="{length:g}"/>'
    if kind == "cylinder_y":
        _, r, length, xyz = shape
        return (
            f'<origin xyz="{_f(xyz)}" rpy="{-math.pi / 2:.9f} 0 0"/>',
            f'<cylinder radius="{r:g}" length="{length:g}"/>',
        )
    if kind == "capsule":
        _, r, p0, p1 = shape
        d = [b - a for a, b in zip(p0, p1)]
        length = math.sqrt(sum(x * x for x in d))
        mid = [(a + b) / 2 for a, b in zip(p0, p1)]
        # Capsule axis is the geometry's z; rotate z onto d.
        if sum(abs(x) > 1e-9 for x in d) > 1:  # oblique: pitch z towards x, then yaw
            rpy = (0.0, math.atan2(math.hypot(d[0], d[1]), d[2]), math.atan2(d[1], d[0]))
        elif abs(d[0]) > 1e-9:
            rpy = (0.0, math.pi / 2, 0.0)
        elif abs(d[1]) > 1e-9:
            rpy = (-math.pi / 2, 0.0, 0.0)
        else:
            rpy = (0.0, 0.0, 0.0)
        return (
            f'<origin xyz="{_f(mid)}" rpy="{_f(rpy)}"/>',
            f'<capsule radius="{r:g}" length="{length:.6g}"/>',
        )
    raise ValueError(kind)


def _shape_inertia(shape):
    """(volume m^3, centroid, 3x3 inertia about the centroid per unit
    density) of a solid shape; a capsule as a cylinder of equal volume."""
    kind = shape[0]
    if kind == "box":
        _, (a, b, c), xyz = shape
        v = a * b * c
        return (
            v,
            list(xyz),
            [[v * (b * b + c * c) / 12, 0, 0], [0, v * (a * a + c * c) / 12, 0], [0, 0, v * (a * a + b * b) / 12]],
        )
    if kind in ("cylinder_x", "cylinder_y", "cylinder_z"):
        _, r, length, xyz = shape
        axis, centre = "xyz".index(kind[-1]), list(xyz)
    else:
        _, r, p0, p1 = shape
        d = [b - a for a, b in zip(p0, p1)]
        axis = max(range(3), key=lambda i: abs(d[i]))
        length = math.sqrt(sum(x * x for x in d)) + 4 * r / 3
        centre = [(a + b) / 2 for a, b in zip(p0, p1)]
    v = math.pi * r * r * length
    across = v * (3 * r * r + length * length) / 12
    inertia = [[across if i == j else 0.0 for j in range(3)] for i in range(3)]
    inertia[axis][axis] = v * r * r / 2
    return v, centre, inertia


def _link_inertial(shapes, density: float) -> str:
    """The URDF inertial of a link's solid shapes at one density (parallel
    axis theorem about the common centre of mass)."""
    parts = [_shape_inertia(s) for s in shapes]
    mass = sum(v for v, _, _ in parts) * density
    com = [sum(v * c[i] for v, c, _ in parts) * density / mass for i in range(3)]
    inertia = [[0.0] * 3 for _ in range(3)]
    for v, c, i_c in parts:
        m, d = v * density, [c[i] - com[i] for i in range(3)]
        dd = sum(x * x for x in d)
        for i in range(3):
            for j in range(3):
                inertia[i][j] += i_c[i][j] * density + m * ((dd if i == j else 0.0) - d[i] * d[j])
    (xx, xy, xz), (_, yy, yz), (_, _, zz) = inertia
    return (
        f'    <inertial><origin xyz="{_f(com)}" rpy="0 0 0"/><mass value="{mass:.6g}"/>'
        f'<inertia ixx="{xx:.6g}" ixy="{xy:.6g}" ixz="{xz:.6g}" iyy="{yy:.6g}" iyz="{yz:.6g}" izz="{zz:.6g}"/>'
        "</inertial>"
    )


def _densities(robot: dict) -> dict:
    """Per link, the density that gives the robot its published mass (the
    gripper its own)."""
    links = robot["links"]
    arm = [n for n in links if n != "gripper" and n not in robot.get("unweighed", ())]
    density = robot["mass"] / sum(_shape_inertia(s)[0] for n in arm for s in links[n])
    out = {n: density for n in links}
    out["gripper"] = robot.get("gripper_mass", GRIPPER_MASS_KG) / sum(_shape_inertia(s)[0] for s in links["gripper"])
    return out


def _uses_drake(robot: dict) -> bool:
    """Whether the URDF needs Drake's XML namespace (its own elements)."""
    return "accelerations" in robot or "unchecked_pairs" in robot


def write_urdf(robot: dict) -> str:
    lines = [
        '<?xml version="1.0"?>',
        "<!-- Generated by tools/make_models.py from the reference numbers; do not edit. -->",
        f'<robot name="{robot["name"]}"' + (' xmlns:drake="http://drake.mit.edu">' if _uses_drake(robot) else ">"),
        f'  <material name="body"><color rgba="{robot["colour"]}"/></material>',
        '  <material name="gripper"><color rgba="0.35 0.35 0.40 1"/></material>',
    ]
    children = dict.fromkeys(j[3] for j in robot["joints"])  # ordered: the same file every run
    densities = _densities(robot)
    all_links = list(robot["links"]) + [c for c in children if c not in robot["links"]]
    for link in all_links:
        lines.append(f'  <link name="{link}">')
        shapes = robot["links"].get(link, [])
        # Solid shapes at the robot's density (see the masses above); a
        # frame-only link gets a token inertia.
        lines.append(
            _link_inertial(shapes, densities[link])
            if shapes
            else '    <inertial><mass value="0.01"/><inertia ixx="1e-5" ixy="0" ixz="0" iyy="1e-5" iyz="0" izz="1e-5"/></inertial>'
        )
        material = "gripper" if link == "gripper" else "body"
        for i, shape in enumerate(shapes):
            origin, geom = _geometry(shape)
            lines.append(
                f'    <visual name="{link}_visual_{i}">{origin}<geometry>{geom}</geometry><material name="{material}"/></visual>'
            )
            lines.append(f'    <collision name="{link}_collision_{i}">{origin}<geometry>{geom}</geometry></collision>')
        lines.append("  </link>")
    efforts = iter(robot.get("efforts", ()))
    accelerations = iter(robot.get("accelerations", ()))
    for name, jtype, parent, child, xyz, axis, lo, hi, vmax in robot["joints"]:
        lines.append(f'  <joint name="{name}" type="{jtype}">')
        lines.append(f'    <parent link="{parent}"/><child link="{child}"/>')
        # A joint frame turned from its parent's (the Panda's DH frames): the
        # angles in full precision, so the kinematics are exact.
        rpy = " ".join(f"{a:.17g}" for a in robot.get("joint_rpy", {}).get(name, (0, 0, 0)))
        lines.append(f'    <origin xyz="{_f(xyz)}" rpy="{rpy}"/>')
        if jtype != "fixed":
            lines.append(f'    <axis xyz="{_f(axis)}"/>')
            effort = next(efforts, 10000)
            # Drake reads an acceleration limit from this attribute
            # (MultibodyPlant.GetAccelerationUpperLimits).
            acceleration = next(accelerations, None)
            extra = "" if acceleration is None else f' drake:acceleration="{acceleration:g}"'
            lines.append(
                f'    <limit lower="{lo:.9f}" upper="{hi:.9f}" velocity="{vmax:.6f}" effort="{effort}"{extra}/>'
            )
        lines.append("  </joint>")
    for a, b in robot.get("unchecked_pairs", ()):  # Drake skips collisions within a group
        lines += [
            f'  <drake:collision_filter_group name="{a}_{b}">',
            f'    <drake:member link="{a}"/><drake:member link="{b}"/>',
            f'    <drake:ignored_collision_filter_group name="{a}_{b}"/>',
            "  </drake:collision_filter_group>",
        ]
    if "efforts" in robot:  # transmissions: Drake makes an actuator for each
        for name, jtype, *_ in robot["joints"]:
            if jtype != "fixed":
                lines += [
                    f'  <transmission name="{name}_transmission">',
                    "    <type>transmission_interface/SimpleTransmission</type>",
                    f'    <joint name="{name}"><hardwareInterface>EffortJointInterface</hardwareInterface></joint>',
                    f'    <actuator name="{name}_motor"><mechanicalReduction>1</mechanicalReduction></actuator>',
                    "  </transmission>",
                ]
    lines.append("</robot>")
    return "\n".join(lines) + "\n"


# -- the mesh test robot -------------------------------------------------------
#
# A 7-DoF arm whose links are all meshes (OBJ), with a compact wrist: links
# 5 and 7 (not adjacent, so Drake does not filter the pair) sit about a
# centimetre apart across link 6, where a bounding box per link would
# overlap. Link 4 is L-shaped (not convex), so its convex hull is larger than
# the mesh. Used by the tests (tests/data/mesh_cell.yaml).


def _prism(r: float, z0: float, z1: float, n: int = 16) -> tuple[list, list]:
    """An n-gon prism about z, from z0 to z1 (radius r at the vertices)."""
    verts = []
    for z in (z0, z1):
        for i in range(n):
            a = 2 * math.pi * i / n
            verts.append((r * math.cos(a), r * math.sin(a), z))
    faces = [tuple(range(n))[::-1], tuple(range(n, 2 * n))]
    for i in range(n):
        j = (i + 1) % n
        faces.append((i, j, n + j, n + i))
    return verts, faces


def _box(lo, hi) -> tuple[list, list]:
    verts = [(x, y, z) for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return verts, faces


def _merge(*parts) -> tuple[list, list]:
    verts, faces = [], []
    for v, f in parts:
        base = len(verts)
        verts += v
        faces += [tuple(base + i for i in face) for face in f]
    return verts, faces


def write_obj(mesh, header: str) -> str:
    verts, faces = mesh
    lines = [f"# {header}"] + [f"v {_f(v)}" for v in verts]
    lines += ["f " + " ".join(str(i + 1) for i in face) for face in faces]
    return "\n".join(lines) + "\n"


MESH_ARM_LINKS = {
    "base": _prism(0.12, 0.0, 0.15),
    "link1": _prism(0.08, 0.0, 0.26),
    "link2": _prism(0.065, -0.02, 0.30),
    "link3": _prism(0.06, 0.0, 0.28),
    # L-shaped (not convex): an upright bar and a foot towards +x.
    "link4": _merge(_box((-0.05, -0.05, -0.02), (0.05, 0.05, 0.30)), _box((0.05, -0.04, -0.02), (0.16, 0.04, 0.05))),
    "link5": _prism(0.05, 0.0, 0.115),
    "link6": _box((-0.035, -0.045, -0.035), (0.035, 0.045, 0.06)),
    # Flange and two fingers.
    "link7": _merge(
        _prism(0.045, 0.0, 0.03),
        _box((-0.04, -0.012, 0.03), (-0.02, 0.012, 0.11)),
        _box((0.02, -0.012, 0.03), (0.04, 0.012, 0.11)),
    ),
}

MESH_ARM_JOINTS = [
    # name, parent, child, xyz, axis, lower, upper, vmax (deg/s)
    ("j1", "base", "link1", (0, 0, 0.15), (0, 0, 1), D(-166), D(166), 150),
    ("j2", "link1", "link2", (0, 0, 0.27), (0, 1, 0), D(-101), D(101), 150),
    ("j3", "link2", "link3", (0, 0, 0.315), (0, 0, 1), D(-166), D(166), 150),
    ("j4", "link3", "link4", (0, 0, 0.29), (0, 1, 0), D(-170), D(-4), 150),
    ("j5", "link4", "link5", (0, 0, 0.31), (0, 0, 1), D(-166), D(166), 180),
    ("j6", "link5", "link6", (0, 0, 0.155), (0, 1, 0), D(-1), D(215), 180),
    ("j7", "link6", "link7", (0, 0, 0.075), (0, 0, 1), D(-166), D(166), 180),
]


def write_mesh_arm() -> list[Path]:
    folder = MODELS / "mesh_arm"
    (folder / "meshes").mkdir(parents=True, exist_ok=True)
    written = []
    for link, mesh in MESH_ARM_LINKS.items():
        out = folder / "meshes" / f"{link}.obj"
        out.write_text(write_obj(mesh, f"mesh_arm {link}; generated by tools/make_models.py"))
        written.append(out)
    lines = [
        '<?xml version="1.0"?>',
        "<!-- Generated by tools/make_models.py: the mesh test robot (7 DoF, compact wrist). -->",
        '<robot name="mesh_arm">',
    ]
    for link in list(MESH_ARM_LINKS) + ["tool"]:
        lines.append(f'  <link name="{link}">')
        lines.append(
            '    <inertial><mass value="1"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>'
        )
        if link != "tool":
            geom = f'<geometry><mesh filename="package://drake_cfvol_models/mesh_arm/meshes/{link}.obj"/></geometry>'
            lines.append(f"    <visual>{geom}</visual>")
            lines.append(f"    <collision>{geom}</collision>")
        lines.append("  </link>")
    for name, parent, child, xyz, axis, lo, hi, vmax in MESH_ARM_JOINTS:
        lines.append(
            f'  <joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{_f(xyz)}"/><axis xyz="{_f(axis)}"/>'
            f'<limit lower="{lo:.9f}" upper="{hi:.9f}" velocity="{D(vmax):.6f}" effort="100"/></joint>'
        )
    lines.append(
        '  <joint name="tool_joint" type="fixed"><parent link="link7"/><child link="tool"/>'
        '<origin xyz="0 0 0.11"/></joint>'
    )
    lines.append("</robot>")
    out = folder / "mesh_arm.urdf"
    out.write_text("\n".join(lines) + "\n")
    written.append(out)
    return written


def main() -> None:
    for robot, folder in ((ABB, "abb_irb6700"), (KUKA, "kuka_kr210"), (IIWA, "iiwa14"), (PANDA, "franka_panda")):
        out = MODELS / folder / f"{robot['name']}.urdf"
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(write_urdf(robot))
        print(f"wrote {out.relative_to(MODELS.parent)}")
    for cell in (AUTOMOTIVE, AEROSPACE, COBOT, FRANKA):
        out = MODELS / "cells" / f"{cell['name']}.sdf"
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(write_cell_sdf(cell))
        print(f"wrote {out.relative_to(MODELS.parent)}")
    for out in write_mesh_arm():
        print(f"wrote {out.relative_to(MODELS.parent)}")


if __name__ == "__main__":
    main()
