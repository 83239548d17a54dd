"""`softcbf list` imports only what it lists (issue 27): not the hardware mode, the bench or the studies' command
line, nor MuJoCo, OpenCV, matplotlib, rerun or numba (the scenario modules import them where a scenario runs), and the
registry imports a built-in's module only when it is looked up. CPU time: tools/bench_cli_list.py."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

LAZY = ("softcbf.hardware_cli", "hardware.runner", "softcbf.bench", "softcbf.study.cli")
HEAVY = ("mujoco", "cv2", "OpenGL", "matplotlib", "rerun", "numba")  # imported only to run a scenario, render or report (numba: the compiled PCC model, controllers.core.lazy_import)


def modules_after(code: str) -> set[str]:
    result = subprocess.run([sys.executable, "-c", code + "\nimport json, sys; print(json.dumps(sorted(sys.modules)))"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    return set(json.loads(result.stdout.strip().splitlines()[-1]))


def test_list_imports_no_other_subcommand():
    loaded = modules_after("import contextlib, io\nfrom softcbf.cli import main\n"
                           "with contextlib.redirect_stdout(io.StringIO()):\n    assert main(['list']) == 0")
    assert loaded.isdisjoint(LAZY), sorted(loaded & set(LAZY))
    assert "controllers.governors.energy_governor" in loaded  # list describes every filter


@pytest.mark.parametrize("argv, shown", [(["list"], "mujoco_contact:"), (["run", "mujoco_contact", "--help"], "--f-max float"),
                                         (["run", "camera_loop", "--help"], "valid: in [16, 1280] px")])
def test_listing_and_scenario_help_import_no_simulator_nor_opencv(argv, shown):
    """Every scenario is registered and its parameters described (defaults, ranges) without MuJoCo or OpenCV."""
    loaded = modules_after("import contextlib, io\nfrom softcbf.cli import main\nout = io.StringIO()\n"
                           f"with contextlib.redirect_stdout(out):\n    assert main({argv!r}) == 0\n"
                           f"assert {shown!r} in out.getvalue(), out.getvalue()")
    assert {"scenarios.paper_sim", "scenarios.mujoco_contact", "scenarios.camera_loop"} <= loaded
    assert loaded.isdisjoint(HEAVY), sorted(loaded & set(HEAVY))


@pytest.mark.parametrize("argv, module", [(["hardware", "--help"], "softcbf.hardware_cli"), (["bench", "--help"], "softcbf.bench"),
                                          (["study", "run", "--help"], "softcbf.study.cli")])
def test_a_lazy_subcommand_still_parses_its_own_options(argv, module, capsys):
    from softcbf.cli import main

    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 0 and "usage: softcbf" in capsys.readouterr().out
    assert module in sys.modules


def test_top_level_help_names_every_subcommand_with_its_help(capsys):
    from softcbf.cli import COMMANDS, main

    with pytest.raises(SystemExit):
        main(["--help"])
    out = " ".join(capsys.readouterr().out.split())
    for command in COMMANDS.values():
        assert command.name in out and " ".join(command.help_text().split())[:30] in out


def test_the_registry_imports_a_builtin_at_its_first_lookup():
    loaded = modules_after("from controllers.registry import FILTERS, NOMINALS\n"
                           "assert 'e-erg' in FILTERS and list(FILTERS) == ['paper-cbf', 'none', 'qsg', 'e-erg', 'c-erg', 'ecbf', 'sdcbf', 'isscbf', 'backup-cbf']\n"
                           "assert len(NOMINALS) == 4 and FILTERS['qsg'].__name__ == 'QuasiStaticGovernor'")
    assert "controllers.governors.quasi_static_governor" in loaded
    assert "controllers.governors.energy_governor" not in loaded and "controllers.cbf.paper_filter" not in loaded
    from controllers.registry import FILTERS

    with pytest.raises(KeyError):
        FILTERS["nosuch"]
    with pytest.raises(TypeError):
        FILTERS["none"] = object  # read-only: the built-ins are fixed


class Recorded(Exception):
    """Raised by `record_params` with the parameters a scenario hands to its SummaryWriter."""


def record_params(out_dir, scenario, params, *args, **kwargs):
    raise Recorded(dict(params))


@pytest.mark.parametrize("name, params", [("paper_sim", {}), ("mujoco_contact", {}),
                                          ("camera_loop", {"calibration": "truth", "width": 64, "height": 48})])
def test_a_run_records_exactly_its_parameters(name, params, tmp_path, monkeypatch):
    """The names a scenario imports inside its function come after it reads its parameters (`locals()`)."""
    import importlib

    from scenarios import get

    scenario = get(name)
    monkeypatch.setattr(importlib.import_module(f"scenarios.{name}"), "SummaryWriter", record_params)
    with pytest.raises(Recorded) as recorded:
        scenario.run(tmp_path, **{"duration": 0.01, "progress": False, **params})
    assert recorded.value.args[0] == scenario.validate({"duration": 0.01, "progress": False, **params})
