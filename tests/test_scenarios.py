"""Scenario registry and CLI (docs/run-outputs.md): list, run, outputs, errors, determinism."""

import json
import subprocess
import sys

import numpy as np
import pytest

from scenarios import get, registry
from scenarios.__main__ import main
from scenarios.common import data_only
from softcbf_mj.outputs.runio import load_timeseries

SPEC_RUN_FIELDS = {
    "tuning": str,
    "rho_min_pred": float,
    "rho_min_meas": (float, type(None)),
    "force_max_N": float,
    "t_violation_s": float,
    "infeasible_steps": int,
    "recovery_steps": int,
    "filter_us_median": (float, type(None)),
    "filter_us_p99": (float, type(None)),
    "wall_s": float,
    "sim_s": float,
}


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "scenarios", *args], capture_output=True, text=True, timeout=300)


def test_list_names_every_scenario_and_its_parameters():
    out = run_cli("--list")
    assert out.returncode == 0, out.stderr
    for name in registry():
        assert name in out.stdout
    assert "--duration float (default 100.0)" in out.stdout
    assert "--pressure-limits bool" in out.stdout


@pytest.mark.slow
def test_paper_sim_writes_the_spec_outputs(tmp_path):
    out_dir = tmp_path / "run"
    res = run_cli("paper_sim", "--out", str(out_dir), "--duration", "2", "--tunings", "None,Low", "--amplitude", "150", "--frequency", "0.25", "--progress", "false")
    assert res.returncode == 0, res.stderr
    assert "rho_min" in res.stdout and "Low" in res.stdout
    summary = json.loads((out_dir / "summary.json").read_text(encoding="utf-8"))
    assert summary["scenario"] == "paper_sim"
    assert summary["params"]["duration"] == 2.0 and summary["params"]["amplitude"] == 150.0
    assert summary["params"]["tunings"] == "None,Low"
    assert {"softcbf_mj", "mujoco", "python"} <= set(summary["versions"])
    config = json.loads((out_dir / "config.json").read_text(encoding="utf-8"))
    assert config["params"] == summary["params"] and config["seed"] == 0
    assert "-m scenarios paper_sim --out" in config["command"]
    scene = summary["scene"]
    assert scene["n_max_m"] == pytest.approx(0.16 / 11.16, rel=1e-15) and scene["f_max_N"] == 0.16
    assert scene["facets"] == {"H": [[0.36, 1.0]], "h": [0.15]} and scene["plates"] == scene["facets"]
    assert scene["stiffness"] == {"law": "LinearStiffness", "k": 11.16} and scene["segment_lengths_m"] == [0.122, 0.122]
    for name in ("recording.rrd", "report.md", "plots/rho.png"):
        assert (out_dir / name).stat().st_size > 0
    assert [r["tuning"] for r in summary["runs"]] == ["None", "Low"]
    for run in summary["runs"]:
        for key, kind in SPEC_RUN_FIELDS.items():
            assert isinstance(run[key], kind), (key, run[key])
        arrays, units = load_timeseries(out_dir / run["timeseries"])
        assert len(arrays["t"]) == 2000 and set(arrays) <= set(units)
        assert run["sim_s"] == pytest.approx(2.0)
    none, low = summary["runs"]
    assert none["filter_us_median"] is None and low["filter_us_median"] > 0
    # 150 hPa at 0.25 Hz drives the unfiltered tip through the facet within 2 s; the filter keeps it in P.
    assert none["rho_min_meas"] < 0 < low["rho_min_meas"]


def test_existing_output_folder_is_refused(tmp_path):
    (tmp_path / "old.txt").write_text("keep")
    res = run_cli("paper_sim", "--out", str(tmp_path), "--duration", "0.01")
    assert res.returncode == 2 and "not empty" in res.stderr and "--overwrite" in res.stderr
    assert (tmp_path / "old.txt").read_text() == "keep"


@pytest.mark.parametrize(
    "args, message",
    [
        (["nosuch", "--out", "x"], "unknown scenario 'nosuch'; available: camera_loop, mujoco_contact, paper_sim"),
        (["paper_sim", "--out", "{out}", "--tunings", "Medium"], "unknown tuning 'Medium'; valid: None, Low, High, HW-Low, HW-High"),
        (["paper_sim", "--out", "{out}", "--duration", "abc"], "--duration: expected float, got 'abc'"),
        (["paper_sim", "--out", "{out}", "--pressure-limits", "maybe"], "--pressure-limits: expected one of"),
        (["paper_sim", "--out", "{out}", "--speed", "3"], "unknown parameter(s) --speed 3 for scenario paper_sim (did you mean '--seed'?); valid: --duration"),
        (["paper_sim", "--out", "{out}", "--duration", "-1"], "duration must be > 0 s, got -1.0"),
        (["paper_sim", "--out", "{out}", "--integrator", "leapfrog"], "integrator must be one of ros2, rk4, euler"),
        (["paper_sim"], "--out DIR is required"),
    ],
)
def test_bad_arguments_name_the_parameter_and_valid_values(tmp_path, capsys, args, message):
    args = [a.replace("{out}", str(tmp_path / "o")) for a in args]
    assert main(args) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o").exists()  # nothing is left that would refuse the corrected command


def test_same_seed_same_arrays(tmp_path):
    params = dict(duration=0.5, tunings="Low", amplitude=150.0, frequency=0.5, q0_std=0.05, seed=7, progress=False)
    scenario = get("paper_sim")
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        with data_only():
            scenario.run(tmp_path / name, **params)
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["config.json", "summary.json", "table.txt", "timeseries"]
    a, _ = load_timeseries(tmp_path / "a" / "timeseries" / "Low.npz")
    b, _ = load_timeseries(tmp_path / "b" / "timeseries" / "Low.npz")
    for key in ("q", "qd", "u", "u_nom", "rho_pred", "contact_force"):
        np.testing.assert_array_equal(a[key], b[key])
    assert np.any(a["q"][0] != 0)  # the seed did perturb the start


def test_in_process_main_matches_the_module_cli(tmp_path, capsys):
    assert main(["--list"]) == 0
    assert "paper_sim" in capsys.readouterr().out


def test_a_spec_names_the_parameter_its_bound_and_the_value():
    """Building a spec checks every value against the vocabulary, then the scenario's narrower range."""
    camera = get("camera_loop").spec
    camera.from_flat({"duration": 1e-9, "facet_offset": -1.0, "drop_rate": 0.0, "seed": 0, "width": 16, "height": 16,
                  "progress": True, "calibration": "truth"})
    for params, message in [
        ({"duration": 0.0}, "duration must be > 0 s, got 0.0"),
        ({"duration": float("inf")}, "duration must be finite and > 0 s, got inf"),
        ({"duration": 1e5}, "duration must be <= 86400 s (a plausibility bound; a value in ms? 100000 ms = 100 s), got 100000.0"),
        ({"facet_offset": 1.5}, "facet_offset must be in [-1, 1] m, got 1.5"),
        ({"drop_rate": 1.0}, "drop_rate must be in [0, 1), got 1.0"),
        ({"seed": -1}, "seed must be >= 0, got -1"),
        ({"t0": float("nan")}, "t0 must be finite, got nan"),  # every float, bounded or not
        ({"width": 4}, "width must be >= 8 px, got 4"),  # the vocabulary's >= 8 px
        ({"width": 8}, "width must be in [16, 1280] px, got 8"),  # then the scenario's
    ]:
        with pytest.raises(ValueError) as exc:
            camera.from_flat(params)
        assert str(exc.value) == message
