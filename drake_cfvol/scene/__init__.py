"""The workcell: its file (schema, line-numbered errors), the Drake scene, its
arrays for the kernel, meshes, and the method's parameters
(``VolumeParams``). Imports ``io`` and ``kernel``.
"""
