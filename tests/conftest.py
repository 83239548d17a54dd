"""Test session set-up: choose MuJoCo's OpenGL backend before any test module imports mujoco.

MuJoCo reads MUJOCO_GL once, at its first import, and several test modules import
`mujoco` before `softcbf_mj`. Importing the package here first applies
`softcbf_mj.gl_backend.configure_mujoco_gl`: a set MUJOCO_GL is kept; unset, it becomes
osmesa on a CPU-only machine such as CI (egl with an NVIDIA GPU).
"""

import softcbf_mj  # noqa: F401  (sets MUJOCO_GL)
