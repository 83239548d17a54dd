"""tools/study_convergence.py: a study's samples at other discretisations against a reference, through the study's
own runner. Runs 0.1 s from the sinusoid's peak (t0 = 25 s), one sample."""

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TOOL = ROOT / "tools" / "study_convergence.py"
STUDY = ROOT / "studies" / "paper_tunings_plate_errors.toml"
SHORT = ["--set", "fixed.t0=25.0", "--set", "fixed.duration=0.1"]


def run_tool(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, str(TOOL), str(STUDY), *args], capture_output=True, text=True, env=env,
                          cwd=ROOT, timeout=600)


def test_parse_overrides_reads_toml_values():
    spec = importlib.util.spec_from_file_location("study_convergence", TOOL)
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    assert tool.parse_overrides("links_per_segment=5,physics_dt=5e-4") == {"links_per_segment": 5, "physics_dt": 5e-4}
    with pytest.raises(ValueError, match="KEY=VALUE of scenario parameters"):
        tool.parse_overrides("fixed.physics_dt=5e-4")


def test_the_reference_itself_has_no_error_and_a_coarser_step_has_some():
    done = run_tool(*SHORT, "--samples", "1", "--reference", "physics_dt=1e-4", "--setting", "physics_dt=1e-4",
                    "--setting", "links_per_segment=5,physics_dt=5e-4")
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout.strip().splitlines()[-1])
    assert report["samples"] == [1] and report["own_setting"] == {"links_per_segment": 10, "physics_dt": 1e-4}
    assert report["tol_force_N"] == pytest.approx(1.6e-3)
    same, coarse = report["settings"]["physics_dt=1e-4"], report["settings"]["links_per_segment=5,physics_dt=5e-4"]
    for exact in (report["settings"]["study"], same):  # the study's own setting is the reference here
        assert exact["worst_force_err_N"] == 0.0 and exact["worst_tip_err_m"] == 0.0 and exact["meets"]
        assert exact["worst_d_rho_min_meas"] == 0.0 and exact["flips"] == [] and exact["failed"] == []
    assert coarse["worst_tip_err_m"] > 0.0  # 0.1 s from rest: no contact yet, the tip differs
    row = report["per_sample"]["links_per_segment=5,physics_dt=5e-4"]["1"]
    assert row["status"] == "ok" and row["tip_err_m"] == coarse["worst_tip_err_m"]
    assert "[study_convergence]" in done.stderr  # progress from the start


@pytest.mark.parametrize("args, message", [
    ([], "give --draws or --samples"),
    (["--samples", "1000"], "sample index must lie in [0, 1000), got 1000"),
    (["--samples", "1", "--setting", "physics_dt=3e-4"], "physics step (0.0003 s"),  # does not divide 1 ms
    (["--samples", "1", "--setting", "no_such_parameter=1"], "no_such_parameter"),
])
def test_bad_input_is_one_line(args, message):
    done = run_tool(*SHORT, *args)
    assert done.returncode != 0 and done.stdout == ""
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("study_convergence: ") and message in lines[0]


def test_sigterm_reports_the_samples_that_are_complete():
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    with subprocess.Popen([sys.executable, str(TOOL), str(STUDY), *SHORT, "--samples", "1,2,3,4", "--setting",
                           "physics_dt=5e-4"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                          cwd=ROOT) as child:
        first = child.stdout.readline()
        assert first.startswith("sample 1: ")
        child.terminate()
        out, err = child.communicate(timeout=120)
    assert child.returncode == 0, err
    report = json.loads(out.strip().splitlines()[-1])
    assert report["samples"][0] == 1 and len(report["samples"]) < 4 and "runs not done" in err
