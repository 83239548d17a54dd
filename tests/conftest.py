"""Test session set-up: choose MuJoCo's OpenGL backend before any test module imports mujoco.

MuJoCo reads MUJOCO_GL once, at its first import, and several test modules import
`mujoco` before `softcbf_mj`. Importing the package here first applies
`softcbf_mj.gl_backend.configure_mujoco_gl`: a set MUJOCO_GL is kept; unset, it becomes
osmesa on a CPU-only machine such as CI (egl with an NVIDIA GPU).
"""

import softcbf_mj  # noqa: F401  (sets MUJOCO_GL)

import pytest  # noqa: E402

from scenarios import get  # noqa: E402

SHORT_PAPER_RUN = dict(duration=0.5, tunings="None,Low", amplitude=150.0, frequency=0.5, progress=False)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A short paper_sim run folder (two tunings, 0.5 s), one per test module: reports and recordings are built from it."""
    out = tmp_path_factory.mktemp("run")
    get("paper_sim").run(out, **SHORT_PAPER_RUN)
    return out
