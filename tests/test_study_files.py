"""Every study file the project ships loads with the reader its users' command uses: a tune file (it has a
`[tune]` table) with `softcbf study tune`'s `load_tune`, every other with `load_study` (`softcbf study run` and
`falsify`), so that a shipped file with an unknown key, a bad range or a deprecated form is caught here, not by a
user."""

from __future__ import annotations

import tomllib
import warnings
from pathlib import Path

import pytest

from softcbf.study.definition import load_study
from softcbf.study.tune import load_tune

STUDIES = sorted((Path(__file__).resolve().parents[1] / "studies").glob("*.toml"))


@pytest.mark.parametrize("path", STUDIES, ids=[p.stem for p in STUDIES])
def test_a_shipped_study_file_loads_without_a_deprecation(path):
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        if "tune" in tomllib.loads(path.read_text(encoding="utf-8")):
            assert load_tune(path).study.vary
        else:
            assert load_study(path).name == path.stem


def test_the_check_sees_a_deprecated_form(tmp_path):
    """The test can fail: the push file with its nominal's parameters as the deprecated 'k=v;k=v' text warns."""
    text = (STUDIES[0].parent / "falsify_standard_box_push.toml").read_text(encoding="utf-8")
    old = text.replace("nominal_params = { seed = 0, low_hPa = 150, high_hPa = 150 }",
                       'nominal_params = "seed=0;low_hPa=150;high_hPa=150"')
    assert old != text
    path = tmp_path / "falsify_standard_box_push.toml"
    path.write_text(old, encoding="utf-8")
    with pytest.raises(DeprecationWarning), warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        load_study(path)
