"""The examples run (short settings): the shield example's CEM behind no filter and behind e-erg (issue 27)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_shield_cem_trains_with_and_without_the_filter_and_plots(tmp_path):
    figure = tmp_path / "shield.png"
    result = subprocess.run([sys.executable, "examples/shield_cem.py", "--iterations", "2", "--population", "3",
                             "--episode-steps", "8", "--figure", str(figure)], cwd=ROOT, capture_output=True, text=True,
                            timeout=600)
    assert result.returncode == 0, result.stderr
    runs = json.loads(result.stdout.strip().splitlines()[-1])
    assert [r["filter"] for r in runs] == ["none", "e-erg:contact_aware=true"]
    for r in runs:
        assert len(r["mean_return"]) == len(r["mean_cost"]) == len(r["cumulative_cost"]) == 2
        assert all(v <= 0 for v in r["mean_return"]) and all(c >= 0 for c in r["mean_cost"])
        assert r["cumulative_cost"] == sorted(r["cumulative_cost"]) and r["episodes"] == 2 * 3 + 1
    assert runs[1]["cumulative_cost"][-1] == 0.0  # behind the energy governor no step goes above F_max
    assert figure.stat().st_size > 10_000


def test_shield_cem_refuses_bad_settings():
    result = subprocess.run([sys.executable, "examples/shield_cem.py", "--population", "1"], cwd=ROOT,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and "--population must be >= 2, got 1" in result.stderr


def _readme_headings() -> set[str]:
    import re

    return {h.strip() for h in re.findall(r"^#+ (.+)$", (ROOT / "README.md").read_text(encoding="utf-8"), re.M)}


def test_examples_cite_readme_sections_and_docs_that_exist():
    """A citation `README, "Section"` names a heading of the README; a docs page cited with a section names one of that
    page's headings (the hardware example cited a README section, "Hardware mode", that no longer existed)."""
    import re

    cited = 0
    for path in sorted((ROOT / "examples").iterdir()):
        text = path.read_text(encoding="utf-8")
        for source, section in re.findall(r"(README|docs/[\w.-]+\.md), \"([^\"]+)\"", text):
            cited += 1
            if source == "README":
                assert section in _readme_headings(), (path.name, section)
            else:
                page = (ROOT / source).read_text(encoding="utf-8")
                assert re.search(rf"^#+ {re.escape(section)}$", page, re.M), (path.name, source, section)
    assert cited >= 1
