"""softcbf-mj: a MuJoCo testbed for force-safe control of soft robots with control barrier functions."""

from softcbf_mj.camera.gl_backend import configure_mujoco_gl

__version__ = "0.1.0"

# MuJoCo reads MUJOCO_GL once, at its first import: choose the offscreen backend before
# any module of this package imports mujoco (rules in softcbf_mj/camera/gl_backend.py).
configure_mujoco_gl()
