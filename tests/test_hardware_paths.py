"""`softcbf hardware`: --filter and --nominal FILE.py:Factory are relative to the working directory (issue 27).

The configuration file's own plug-in files stay relative to its folder (hardware.config.plugin_spec)."""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import pytest

from softcbf.hardware_cli import add_arguments, configure

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
NOMINAL = "import numpy as np\n\ndef Hold(context, u_hPa: float = 10.0):\n    return lambda t, q, qd: np.full(2, u_hPa)\n"


def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    return parser.parse_args(list(argv))


@pytest.fixture
def layout(tmp_path, monkeypatch):
    """cwd/ holds the plug-ins, conf/ the configuration (as examples/ does, with its robot file)."""
    conf, cwd = tmp_path / "conf", tmp_path / "cwd"
    conf.mkdir()
    (cwd / "plugins").mkdir(parents=True)
    for name in ("hardware_emulated.toml", "hardware_slow_arm_robot.json"):
        shutil.copy(EXAMPLES / name, conf / name)
    shutil.copy(EXAMPLES / "clip_filter.py", cwd / "plugins" / "clip_filter.py")
    (cwd / "plugins" / "hold.py").write_text(NOMINAL)
    monkeypatch.chdir(cwd)
    return conf, cwd


def test_filter_and_nominal_files_on_the_command_line_are_relative_to_the_working_directory(layout):
    conf, cwd = layout
    args = parse(str(conf / "hardware_emulated.toml"), "--filter", "plugins/clip_filter.py:ClipFilter",
                 "--filter-param", "limit_hPa=100", "--nominal", "plugins/hold.py:Hold")
    config = configure(args)  # builds both once: a wrong folder would be a ConfigError
    assert config.plugin_spec(config.control.filter) == f"{cwd / 'plugins' / 'clip_filter.py'}:ClipFilter"
    assert config.plugin_spec(config.control.nominal) == f"{cwd / 'plugins' / 'hold.py'}:Hold"


def test_the_readme_command_resolves_from_the_repository_root(monkeypatch):
    """`softcbf hardware examples/hardware_emulated.toml --filter examples/clip_filter.py:ClipFilter` (README): was
    "no such Python file 'examples/examples/clip_filter.py'"."""
    monkeypatch.chdir(EXAMPLES.parent)
    config = configure(parse("examples/hardware_emulated.toml", "--filter", "examples/clip_filter.py:ClipFilter",
                             "--filter-param", "limit_hPa=100"))
    assert config.plugin_spec(config.control.filter) == f"{EXAMPLES / 'clip_filter.py'}:ClipFilter"


def test_names_and_modules_are_not_paths_and_the_files_own_specs_stay_relative_to_it(layout):
    conf, _ = layout
    (conf / "mine.py").write_text(NOMINAL)
    text = (conf / "hardware_emulated.toml").read_text()
    (conf / "hardware_emulated.toml").write_text('nominal = "mine.py:Hold"\n' + text)
    config = configure(parse(str(conf / "hardware_emulated.toml"), "--filter", "none"))
    assert config.control.filter == "none"
    assert config.plugin_spec(config.control.nominal) == f"{conf / 'mine.py'}:Hold"
    config = configure(parse(str(conf / "hardware_emulated.toml"), "--nominal", "controllers.nominal:sinusoid"))
    assert config.control.nominal == "controllers.nominal:sinusoid"
