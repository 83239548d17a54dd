"""Test session set-up: choose MuJoCo's OpenGL backend before any test module imports mujoco.

MuJoCo reads MUJOCO_GL once, at its first import, and several test modules import
`mujoco` before `softcbf_mj`. Importing the package here first applies
`softcbf_mj.camera.gl_backend.configure_mujoco_gl`: a set MUJOCO_GL is kept; unset, it becomes
osmesa on a CPU-only machine such as CI (egl with an NVIDIA GPU).

Under pytest-xdist the controlling process first compiles the numba kernels (`pytest_sessionstart`, before the
workers start: `KERNEL_WARM_UP`, the short runs of the first-output tests, in a child process), so that no worker
meets a compile inside a wall-clock test or races another worker compiling the same kernel; with the kernels cached
it costs the child's imports and runs (seconds). In one process nothing is warmed: the first test that steps a
kernel compiles it, and the hardware loop warms its own filter before its timed loop (hardware.runner).

Also: the `run_dir` fixture (a short paper_sim run folder per test module, copied from one run per process), the
`--cpu-durations=N` option (the tests that took the most CPU time; below) and `realtime_alone`: under pytest-xdist a
test of the xdist group "realtime" (wall-clock deadlines: the emulated hardware, the link, first-output times) runs
with every other worker idle. Each test holds a shared lock on a file of the session's base folder, a realtime test
the exclusive one; a realtime test first takes an exclusive "gate" that other tests pass through before their shared
lock, so that a worker starting test after test cannot keep it waiting. Without xdist nothing is locked. A test of
that group is also marked `realtime` (`pytest_collection_modifyitems`), so that `-m realtime` / `-m "not realtime"`
select it.
"""

import softcbf_mj  # noqa: F401  (sets MUJOCO_GL)

import contextlib  # noqa: E402
import fcntl  # noqa: E402
import os  # noqa: E402
import resource  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402

from scenarios import get  # noqa: E402
from scenarios.run_outputs import data_only  # noqa: E402

REALTIME_GROUP = "realtime"
ROOT = Path(__file__).resolve().parents[1]
# The short runs of tests/test_first_output.py, one process: what they step compiles (the paper's PCC plant and CBF,
# the MuJoCo plant, the recommended filter); they draw no run reports (`data_only`): only their kernels matter.
KERNEL_WARM_UP = """
import contextlib, io, sys
from scenarios.run_outputs import data_only
from softcbf.cli import main
out = sys.argv[1]
with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
    for k, argv in enumerate((["run", "mujoco_contact", "--tunings", "Low"], ["run", "paper_sim", "--tunings", "Low"],
                              ["demo"])):
        with data_only():
            code = main([*argv, "--duration", "0.2", "--out", f"{out}/{k}"])
        if code != 0:
            raise SystemExit(f"{argv}: exit {code}")
"""


def pytest_sessionstart(session):
    """Under pytest-xdist, in the controlling process: compile the kernels before the workers start (module
    docstring). Runs before xdist's own session start (which is trylast), so no worker exists yet."""
    config = session.config
    if getattr(config.option, "dist", "no") == "no" or hasattr(config, "workerinput"):
        return
    with tempfile.TemporaryDirectory() as out:
        done = subprocess.run([sys.executable, "-c", KERNEL_WARM_UP, out], cwd=out, capture_output=True, text=True,
                              env={**os.environ, "PYTHONPATH": os.pathsep.join(
                                  filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))})
    if done.returncode != 0:
        last = (done.stderr or done.stdout or f"exit {done.returncode}").strip().splitlines()[-1]
        raise pytest.UsageError(f"the kernel warm-up (tests/conftest.py) failed: {last}")


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """A test of the xdist group "realtime" is also marked `realtime`, before `-m` selects: `-m realtime` and
    `-m "not realtime"` (.ci/run's two phases) split the suite by the one declaration each test already has."""
    for item in items:
        group = item.get_closest_marker("xdist_group")
        if group is not None and group.args and group.args[0] == REALTIME_GROUP:
            item.add_marker(pytest.mark.realtime)


@contextlib.contextmanager
def locked(path, mode):
    """`path` (created if missing) held under fcntl.flock `mode` for the block."""
    with open(path, "a+") as handle:
        fcntl.flock(handle, mode)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


@pytest.fixture(autouse=True)
def realtime_alone(request, tmp_path_factory):
    """Under pytest-xdist, a "realtime" test runs alone (module docstring)."""
    if "PYTEST_XDIST_WORKER" not in os.environ:
        yield
        return
    shared = tmp_path_factory.getbasetemp().parent  # every worker's base folder lies in the session's
    group = request.node.get_closest_marker("xdist_group")
    if group is not None and group.args and group.args[0] == REALTIME_GROUP:
        with locked(shared / "realtime.gate", fcntl.LOCK_EX), locked(shared / "realtime.lock", fcntl.LOCK_EX):
            yield
        return
    with locked(shared / "realtime.gate", fcntl.LOCK_SH):
        pass
    with locked(shared / "realtime.lock", fcntl.LOCK_SH):
        yield


SHORT_PAPER_RUN = dict(duration=0.5, tunings="None,Low", amplitude=150.0, frequency=0.5, progress=False)


def short_paper_run(tmp_path_factory) -> Path:
    """A new short paper_sim run folder (two tunings, 0.5 s)."""
    out = tmp_path_factory.mktemp("run")
    get("paper_sim").run(out, **SHORT_PAPER_RUN)
    return out


@pytest.fixture(scope="session")
def paper_run(tmp_path_factory):
    """The short paper_sim run once per process; tests read `run_dir`'s copies of it."""
    return short_paper_run(tmp_path_factory)


@pytest.fixture(scope="module")
def run_dir(paper_run, tmp_path_factory):
    """A short paper_sim run folder (two tunings, 0.5 s), one per test module: reports and recordings are built from it.
    A copy of the session's `paper_run` (same folder name, files and modification times; the run is deterministic), so
    that a module that rewrites it leaves the next one a fresh run. Only the recording's id differs from a run written
    in the copy's folder (it derives from the folder's path): `own_run_dir` is one written in place."""
    out = tmp_path_factory.mktemp("run_copy") / paper_run.name
    shutil.copytree(paper_run, out)
    return out


@pytest.fixture
def no_run_reports():
    """Scenario runs inside the test write their data alone, no run report or recording
    (`scenarios.run_outputs.data_only`): for the tests of studies and the bench, which read rows and never a run
    folder's plots (a falsification's worst/ replay, kept runs). tests/test_run_outputs.py tests when they are drawn."""
    with data_only():
        yield


@pytest.fixture(scope="module")
def own_run_dir(tmp_path_factory):
    """A short paper_sim run written in its own folder, one per test module that asks."""
    return short_paper_run(tmp_path_factory)



# --cpu-durations=N: the N tests that took the most CPU time (this process and the children it waited for: setup, call
# and teardown together). On a machine that other jobs load, --durations (wall time) grows with the load; CPU time
# barely does, so this is the list to compare between runs. Works under pytest-xdist: each worker attaches its figure
# to the test's report (user_properties), which reaches the controlling process, whose plugin lists them.
CPU_PROPERTY = "cpu_s"
CPU_START = pytest.StashKey[float]()


def pytest_addoption(parser):
    parser.addoption("--cpu-durations", type=int, default=None, metavar="N",
                     help="show the N tests that took the most CPU time, this process and its children (0: all)")


def pytest_configure(config):
    count = config.getoption("cpu_durations")
    if count is not None:
        if count < 0:
            raise pytest.UsageError(f"--cpu-durations must be >= 0, got {count}")
        config.pluginmanager.register(CpuDurations(count), "cpu_durations")


def cpu_seconds() -> float:
    """User + system CPU s of this process and of its children that have been waited for."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


class CpuDurations:
    """Measures each test's CPU time where it runs and lists the largest at the end of the session."""

    def __init__(self, count: int) -> None:
        self.count = count
        self.seconds: dict[str, float] = {}

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(self, item, nextitem):
        item.stash[CPU_START] = cpu_seconds()
        yield

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_makereport(self, item, call):
        outcome = yield
        if call.when == "teardown" and CPU_START in item.stash:
            outcome.get_result().user_properties.append((CPU_PROPERTY, cpu_seconds() - item.stash[CPU_START]))

    def pytest_runtest_logreport(self, report):
        for name, value in report.user_properties:
            if name == CPU_PROPERTY:
                self.seconds[report.nodeid] = value

    def pytest_terminal_summary(self, terminalreporter):
        ranked = sorted(self.seconds.items(), key=lambda entry: entry[1], reverse=True)
        shown = ranked if self.count == 0 else ranked[:self.count]
        terminalreporter.write_sep("=", f"slowest {len(shown)} tests by CPU time (of {len(ranked)}; "
                                        f"{sum(self.seconds.values()):.1f} CPU s in all)")
        for nodeid, seconds in shown:
            terminalreporter.write_line(f"{seconds:8.2f}s cpu  {nodeid}")
