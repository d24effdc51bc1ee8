"""Colours shared by the Meshcat views, the recordings and the plots (RGBA,
0..1). The robot's colour differs from every obstacle category's."""

#: Obstacle colours by category.
CATEGORY_COLOURS = {
    "trail": (0.95, 0.60, 0.10, 1.0),
    "goal": (0.20, 0.45, 0.95, 1.0),
    "no_goal": (0.55, 0.55, 0.60, 1.0),
}
#: The floor, whatever its category.
FLOOR_COLOUR = (0.75, 0.75, 0.72, 1.0)
#: The height-map volume V (semi-transparent).
VOLUME_COLOUR = (0.15, 0.80, 0.30, 0.30)
#: The nominal tool path.
PATH_COLOUR = (0.9, 0.1, 0.1, 1.0)
#: The robot in co-manipulation recordings (violet: unlike every category,
#: the floor, the volume and the path).
ROBOT_COLOUR = (0.55, 0.30, 0.85, 1.0)
#: Names of the category colours, for legends.
COLOUR_NAMES = {"trail": "orange", "goal": "blue", "no_goal": "grey"}
