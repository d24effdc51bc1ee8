"""drake_cfvol's bundled robot and cell models (a ROS-style package, see package.xml)."""
