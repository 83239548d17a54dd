"""The OpenGL backend of MuJoCo's offscreen renderer (MUJOCO_GL), chosen before MuJoCo is imported.

MuJoCo's Python bindings read the environment variable MUJOCO_GL once, when `mujoco` is
first imported, and bind their GL context to it: "osmesa" (software rendering on the CPU,
libOSMesa), "egl" (headless rendering on a GPU, libEGL and a GPU driver) or "glfw" (the
default: a window, which needs a display). `softcbf_mj/__init__.py` calls
`configure_mujoco_gl()` before any module of the package imports MuJoCo:

- MUJOCO_GL set (any value): honoured as it is;
- unset, on Linux: "egl" if an NVIDIA driver is present (/dev/nvidiactl) and libEGL is
  installed, else "osmesa" if libOSMesa is installed (CPU-only machines; `scripts/setup.sh`
  installs it), else left unset (physics works; creating a renderer then fails with
  `RenderBackendError`, which names the fix). Machines with other GPUs set MUJOCO_GL=egl
  themselves. Other systems: left unset (MuJoCo's own choice).

MuJoCo 4.0.0 with MUJOCO_GL=osmesa but no libOSMesa fails inside `import mujoco` itself
(PyOpenGL's `AttributeError: 'NoneType' object has no attribute 'glGetError'`), so
`configure_mujoco_gl` raises an `ImportError` with the fix instead. `softcbf_mj.camera.render`
reads MUJOCO_GL again when it creates a renderer, so a process that imported `mujoco`
before `softcbf_mj` still renders with the backend chosen here.
"""

from __future__ import annotations

import ctypes.util
import os
import sys
from collections.abc import MutableMapping

NVIDIA_DEVICE = "/dev/nvidiactl"
_LIBRARY = {"osmesa": "OSMesa", "egl": "EGL"}  # name for ctypes.util.find_library


def library_available(backend: str) -> bool:
    """True when the shared library that `backend` ("osmesa" or "egl") loads is installed."""
    return ctypes.util.find_library(_LIBRARY[backend]) is not None


def fix_for(backend: str) -> str:
    """What to do when MuJoCo cannot render offscreen with `backend` (a MUJOCO_GL value)."""
    if backend == "osmesa":
        return (
            "install OSMesa for CPU rendering: run `bash scripts/setup.sh` (as root) or "
            "`apt-get install libosmesa6`; on a machine with a GPU set MUJOCO_GL=egl instead"
        )
    if backend == "egl":
        return (
            "EGL needs a GPU driver with libEGL; on a CPU-only machine set MUJOCO_GL=osmesa "
            "(and run `bash scripts/setup.sh`, or `apt-get install libosmesa6`)"
        )
    return (
        f"MUJOCO_GL={backend or '(unset)'} (glfw, also MuJoCo's choice when unset) renders through a window and "
        "needs a display; for offscreen rendering set MUJOCO_GL=osmesa (CPU; run `bash scripts/setup.sh` or "
        "`apt-get install libosmesa6`) or MUJOCO_GL=egl (GPU)"
    )


def configure_mujoco_gl(environ: MutableMapping[str, str] = os.environ, platform: str = sys.platform) -> str:
    """Set MUJOCO_GL in `environ` when unset (rules in the module docstring); return its value ("" if unset)."""
    requested = environ.get("MUJOCO_GL", "").strip().lower()
    if not platform.startswith("linux"):
        return requested
    if requested == "osmesa" and not library_available("osmesa"):
        raise ImportError(f"MUJOCO_GL=osmesa but libOSMesa is not installed: {fix_for('osmesa')}")
    if requested:
        return requested
    if os.path.exists(NVIDIA_DEVICE) and library_available("egl"):
        environ["MUJOCO_GL"] = "egl"
    elif library_available("osmesa"):
        environ["MUJOCO_GL"] = "osmesa"
    return environ.get("MUJOCO_GL", "")
