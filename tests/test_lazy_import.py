"""`controllers.core.lazy_import.lazy_module` under threads: several threads that touch a deferred module at the same time
all find the loaded module (importlib's LazyLoader on Python 3.11 hands the others an empty module: AttributeError),
its code runs once, and a failed load leaves nothing half-filled. The first touch happens once per process, so each
trial is a fresh interpreter."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

THREADS = 4
TRIALS = 12

FIRST_TOUCH = textwrap.dedent("""
    import json, sys, threading
    from controllers.model import dynamics, pcc
    from controllers.governors import energy_governor  # each holds a deferred module
    reads = [(dynamics.pcc_model, "model_terms"), (pcc.pcc_model, "parameter_rows"),
             (energy_governor.energy_kernels, "table_values")]  # energy_kernels imports pcc_model in turn
    barrier = threading.Barrier({threads})
    errors = []

    def touch(i):
        module, name = reads[i % len(reads)]
        barrier.wait()
        try:
            getattr(module, name)
        except Exception as error:
            errors.append(repr(error))

    threads = [threading.Thread(target=touch, args=(i,)) for i in range({threads})]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    print(json.dumps({{"errors": errors, "plain": type(sys.modules["controllers.model.pcc_model"]).__name__,
                      "same": dynamics.pcc_model is sys.modules["controllers.model.pcc_model"] is pcc.pcc_model}}))
""")


def run_python(code: str) -> dict:
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("trial", range(TRIALS))
def test_threads_touching_a_deferred_module_first_all_find_it_loaded(trial):
    outcome = run_python(FIRST_TOUCH.format(threads=THREADS))
    assert outcome == {"errors": [], "plain": "module", "same": True}


def make_package(root, body: str) -> None:
    package = root / "deferred_pkg"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "slow.py").write_text(body)


def test_its_code_runs_once_however_many_threads_wait(tmp_path):
    make_package(tmp_path, "import time\nimport deferred_pkg\ndeferred_pkg.RUNS = getattr(deferred_pkg, 'RUNS', 0) + 1\n"
                           "time.sleep(0.2)\nVALUE = 42\n")
    code = textwrap.dedent(f"""
        import json, sys, threading
        sys.path.insert(0, {str(tmp_path)!r})
        from controllers.core.lazy_import import lazy_module
        import deferred_pkg
        slow = lazy_module("deferred_pkg.slow")
        assert lazy_module("deferred_pkg.slow") is slow  # one placeholder per name
        seen = []
        threads = [threading.Thread(target=lambda: seen.append(slow.VALUE)) for _ in range(8)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        print(json.dumps({{"seen": seen, "runs": deferred_pkg.RUNS}}))
    """)
    assert run_python(code) == {"seen": [42] * 8, "runs": 1}


def test_a_failed_load_raises_at_every_access_not_an_empty_module(tmp_path):
    make_package(tmp_path, "VALUE = 1\nraise RuntimeError('broken at import')\n")
    sys.path.insert(0, str(tmp_path))
    try:
        from controllers.core.lazy_import import lazy_module

        broken = lazy_module("deferred_pkg.slow")
        for _ in range(2):
            with pytest.raises(RuntimeError, match="broken at import"):
                broken.VALUE
    finally:
        sys.path.remove(str(tmp_path))
        for name in ("deferred_pkg.slow", "deferred_pkg"):
            sys.modules.pop(name, None)


def test_an_unknown_module_is_refused_at_once():
    from controllers.core.lazy_import import lazy_module

    with pytest.raises(ImportError, match="no module named 'controllers.nosuch'"):
        lazy_module("controllers.nosuch")


def test_a_deferred_submodule_is_an_attribute_of_its_package_as_after_an_import():
    """`import package.child` after `lazy_module("package.child")` finds the module in sys.modules and binds the
    package: the package must then hold the child, as after an ordinary import."""
    code = textwrap.dedent("""
        import json, sys
        import closedloop.step
        import closedloop.kernels
        print(json.dumps({"same": closedloop.kernels is sys.modules["closedloop.kernels"]}))
    """)
    assert run_python(code) == {"same": True}
