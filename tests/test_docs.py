"""docs/: every example file loads with the project's own loader and is the one the page
shows, every Python block runs, every relative link and anchor resolves, and no code or
model README cites the old out-of-repository specification; the site opens on what the testbed
is, a picture and the way to getting-started.md, and holds the README with its links re-aimed
(docs/hooks/readme_page.py); the user pages carry no history (commit ids, issue numbers, dates:
CHANGELOG.md holds it)."""

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from controllers.model.params import RobotParams, reference_robot
from controllers.model.safe_set import ForceSafeSet, LinearStiffness, paper_safe_set
from controllers.contract.safety_filter import Estimate, FilterContext, FilterOutput
from hardware.config import HardwareConfig
from scenarios.common import load_environment, load_robot
from softcbf.study import load_study

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
EXAMPLES = DOCS / "examples"
EXAMPLE_BLOCK = re.compile(r"<!-- example: (\S+) -->\n```\w*\n(.*?)```", re.S)
LINK = re.compile(r"\]\(([^)\s]+)\)")
OLD_CITATIONS = ("SPEC" + " §", "shared/" + "SPEC.md")  # spelled apart so that this file does not cite it


def _blocks(page: str, tag: str) -> list[str]:
    text = (DOCS / page).read_text(encoding="utf-8")
    return re.findall(rf"<!-- run: {tag} -->\n```python\n(.*?)```", text, re.S)


def test_file_format_blocks_are_the_example_files_and_every_example_is_shown():
    text = (DOCS / "file-formats.md").read_text(encoding="utf-8")
    shown = {name: body for name, body in EXAMPLE_BLOCK.findall(text)}
    assert set(shown) == {"examples/robot.json", "examples/environment.json", "examples/study.toml",
                          "examples/hardware.toml", "examples/run.toml"}
    for name, body in shown.items():
        assert (DOCS / name).read_text(encoding="utf-8") == body, name


def test_robot_example_is_the_reference_arm():
    robot = RobotParams.load(EXAMPLES / "robot.json")
    assert load_robot(str(EXAMPLES / "robot.json")) == robot
    np.testing.assert_allclose(robot.array("gains"), reference_robot().array("gains"), rtol=1e-6)
    np.testing.assert_allclose(robot.array("inertias"), reference_robot().array("inertias"), rtol=1e-5)
    for name in ("lengths", "masses", "stiffness", "damping", "u_min", "u_max"):
        np.testing.assert_array_equal(robot.array(name), reference_robot().array(name))


def test_environment_example_builds_a_force_safe_set_with_a_vertical_wall():
    env = load_environment(str(EXAMPLES / "environment.json"))
    assert env.n_facets == 2
    for scaling in ("paper", "unit"):
        safe_set = ForceSafeSet(env, LinearStiffness(11.16), 0.16, row_scaling=scaling)
        assert safe_set.H_prime.shape == (3, 2)  # two Lemma rows and one vertex correction
        assert safe_set.contains(np.array([0.2, 0.0]))  # the straight arm's tip region is free
        assert not safe_set.contains(np.array([0.26 + 0.02, 0.0]))  # 20 mm into the wall: beyond n_max = 14.3 mm


def test_study_example_is_a_3_by_3_grid():
    study = load_study(EXAMPLES / "study.toml")
    assert study.scenario == "mujoco_contact" and study.sampling == "grid"
    assert study.tunings == ("None", "Low", "HW-High") and study.n_samples == 9
    assert [s.values["true_gain_scale"] for s in map(study.sample, range(0, 9, 3))] == pytest.approx([0.9, 1.0, 1.1])


def test_hardware_example_loads_and_resolves_its_robot_file():
    config = HardwareConfig.load(EXAMPLES / "hardware.toml")
    assert config.robot_params() == RobotParams.load(EXAMPLES / "robot.json")
    assert config.control.tuning == "HW-High" and config.control.control_rate == 10.0


def test_example_filters_keep_to_the_contract():
    from importlib.util import module_from_spec, spec_from_file_location

    spec = spec_from_file_location("my_filters", EXAMPLES / "my_filters.py")
    module = module_from_spec(spec)
    spec.loader.exec_module(module)
    estimate = Estimate(t=0.0, q=np.zeros(2), qd=np.zeros(2), t_capture=0.0)
    np.testing.assert_array_equal(module.ClipFilter(limit_hPa=100.0)(estimate, np.array([150.0, -20.0])), [100.0, -20.0])
    robot, safe_set = reference_robot(), paper_safe_set()
    context = FilterContext(robot=robot, safe_set=safe_set, u_min=robot.array("u_min"), u_max=robot.array("u_max"),
                            control_dt=1e-3)
    scaler = module.RestShapeScaler(margin_m=0.001, steps=50, context=context)
    out = scaler(estimate, np.array([50.0, 50.0]))
    assert isinstance(out, FilterOutput) and out.action == "nominal" and out.diagnostics == {"scale": 1.0}
    from controllers.model.pcc import tip_position

    gain = robot.array("gains") / robot.array("stiffness")
    rows = np.hypot(safe_set.H_prime[:, 0], safe_set.H_prime[:, 1])
    for u_nom in ([80.0, 80.0], [150.0, 150.0], [150.0, -150.0]):
        out = scaler(estimate, np.array(u_nom))
        s = out.diagnostics["scale"]
        assert out.action == "scaled" and 0 < s < 1
        slack = lambda scale: np.min((safe_set.h_prime - safe_set.H_prime @ tip_position(gain * scale * np.array(u_nom),
                                                                                          robot.array("lengths"))) / rows)
        assert slack(s) >= 0.001 - 1e-12  # the returned command's rest shape keeps the margin …
        assert slack(s + 1 / 50) < 0.001  # … and the next larger scale would not
    with pytest.raises(ValueError, match="margin_m must be >= 0 m, got -1"):
        module.RestShapeScaler(margin_m=-1, context=context)


@pytest.mark.parametrize("page, tag", [("quickstart.md", "quickstart"), ("extending.md", "extending")])
def test_python_blocks_run(page, tag, tmp_path):
    blocks = _blocks(page, tag)
    assert blocks, page
    (tmp_path / "docs").symlink_to(DOCS)
    script = tmp_path / "blocks.py"
    script.write_text("\n".join(blocks), encoding="utf-8")
    result = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=600,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert result.returncode == 0, result.stderr[-3000:]
    if tag == "quickstart":
        assert "High: rho_min +" in result.stdout and "qp False rho_pred 0.487" in result.stdout
        assert (tmp_path / "runs" / "quickstart" / "plots" / "overview.svg").is_file()


def test_the_getting_started_block_reads_a_run_folder(tmp_path):
    """The page's Python block, on a short run of its command (the same scenario and push, saved where the page's
    command writes it)."""
    from scenarios.api import MujocoContact, Nominal, Run, run, save

    (block,) = _blocks("getting-started.md", "getting-started")
    page = (DOCS / "getting-started.md").read_text(encoding="utf-8")
    assert "--amplitude 150 --frequency 0.25 --t0 1 --duration 5 --out runs/first" in page
    save(run(MujocoContact(run=Run(duration=0.2, progress=False), nominal=Nominal(amplitude=150.0, frequency=0.25,
                                                                                 t0=1.0))), tmp_path / "runs/first")
    script = tmp_path / "block.py"
    script.write_text(block, encoding="utf-8")
    result = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=600,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert result.returncode == 0, result.stderr[-3000:]
    lines = result.stdout.splitlines()
    assert [line.split(":")[0].strip() for line in lines[:3]] == ["None", "Low", "High"], lines
    assert re.fullmatch(r"\(200,\) N \(measured\) hPa .*", lines[3]), lines


def _anchors(path: Path) -> set[str]:
    """GitHub's heading anchors: lower case, punctuation dropped, spaces → '-'."""
    heads = re.findall(r"^#+ (.+)$", path.read_text(encoding="utf-8"), re.M)
    return {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-") for h in heads}


def test_links_and_anchors_resolve():
    pages = sorted(DOCS.glob("*.md"))
    for page in pages:
        for target in LINK.findall(page.read_text(encoding="utf-8")):
            if target.startswith(("http://", "https://")):
                continue
            file, _, anchor = target.partition("#")
            path = (page.parent / file) if file else page
            assert path.exists(), (page.name, target)
            if anchor:
                assert anchor in _anchors(path), (page.name, target)


def test_code_cites_docs_not_the_external_specification():
    """Every docs/ page and anchor cited in code and model READMEs exists; nothing cites the
    specification outside the repository (README.md and CHANGELOG.md are the integrator's)."""
    files = subprocess.run(["git", "ls-files", "*.py", "*.md", "*.toml"], cwd=ROOT, capture_output=True, text=True,
                           check=True).stdout.split()
    cited = set()
    for name in files:
        if name in ("README.md", "CHANGELOG.md") or not (ROOT / name).is_file():
            continue
        text = (ROOT / name).read_text(encoding="utf-8")
        assert not any(old in text for old in OLD_CITATIONS), name
        cited.update(re.findall(r"docs/([\w.-]+\.md)(?:#([\w-]+))?", text))
    assert cited
    for page, anchor in cited:
        assert (DOCS / page).is_file(), page
        if anchor:
            assert anchor in _anchors(DOCS / page), (page, anchor)


def test_no_file_refers_to_a_path_outside_the_repository():
    """README, docs, docstrings and configurations name no path beside or above the clone (the
    shared specification's folder, a developer's machine); CHANGELOG.md keeps its history."""
    outside = ("../" + "shared", "/" + "work/", "/" + "root/", "/" + "home/")
    files = subprocess.run(["git", "ls-files", "*.py", "*.md", "*.toml", "*.json"], cwd=ROOT, capture_output=True,
                           text=True, check=True).stdout.split()
    offending = [(name, path) for name in files if name != "CHANGELOG.md" and (ROOT / name).is_file()
                 for path in outside if path in (ROOT / name).read_text(encoding="utf-8")]
    assert offending == []


def test_the_readme_names_the_recommended_filter_that_softcbf_list_marks():
    """The README's recommended filter is one preset (`controllers.registry.PRESETS`), the setting that c-erg's
    docstring (what `softcbf list` marks) names and `energy_governor.RECOMMENDED` holds (tools/bench_governors.py
    times it) with the bench's plate interval, and it builds on the reference arm."""
    from controllers.governors.energy_governor import RECOMMENDED, ContactEnergyGovernor
    from controllers.registry import FILTERS, PRESETS, build_filter, typed_params

    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    named = re.findall(r"\*\*The recommended filter\*\* for contact tasks is the preset `([^`]+)`", readme)
    assert named == ["c-erg:recommended"], "the README names the recommended filter once, by its preset"
    preset = PRESETS[named[0]]
    assert FILTERS[preset.filter] is ContactEnergyGovernor
    marked = re.fullmatch(r"Recommended for contact tasks with (.*) \(README\): .*",
                          ContactEnergyGovernor.__doc__.splitlines()[0]).group(1)
    assert typed_params("c-erg", dict(pair.split("=") for pair in marked.split(", "))) == RECOMMENDED
    assert typed_params(named[0]) == {**RECOMMENDED, "stiffness_lo_ratio": 0.9, "stiffness_hi_ratio": 1.1}
    robot = reference_robot()
    context = FilterContext(robot, paper_safe_set(), robot.array("u_min"), robot.array("u_max"), 0.1, 0.02, 0.05)
    governor = build_filter(named[0], {}, context)
    assert (*governor.gain_interval(), governor.params.gain_rest_s) == (0.9, 1.1, 0.2)
    out = governor(Estimate(0.0, np.zeros(2), np.zeros(2), 0.0), np.full(2, 150.0))
    assert np.all(np.isfinite(out.u)) and np.all(out.u <= robot.array("u_max"))


# -- the site ----------------------------------------------------------------------------------------------------


def readme_hook():
    from importlib.util import module_from_spec, spec_from_file_location

    spec = spec_from_file_location("readme_page", DOCS / "hooks" / "readme_page.py")
    module = module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_site_opens_on_the_testbed_a_picture_and_getting_started():
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"))
    hook = readme_hook()
    assert config["hooks"] == ["docs/hooks/readme_page.py"]
    first = config["nav"][0]
    assert list(first) == ["Getting started"]
    assert first["Getting started"] == [{"Home": "README.md"}, "getting-started.md", {"Project README": hook.PAGE}]
    home = (DOCS / "README.md").read_text(encoding="utf-8")
    assert "](figures/demo_force.png)" in home and (DOCS / "figures/demo_force.png").is_file()
    assert home.index("](getting-started.md)") < home.index("## Use it")  # the way in comes before the map
    assert "§" not in home  # no section numbers of a specification the reader never saw
    guide = (DOCS / "getting-started.md").read_text(encoding="utf-8")
    for heading in ("## Set up", "## See the point: `softcbf demo`", "## A first run", "## Reading a run folder",
                    "## Where to go next"):
        assert heading in guide


def test_the_readme_page_links_only_to_pages_and_files_of_the_site():
    """Every link of the README's page lands on a docs page (with the anchor it names) or a file of docs/, or is a URL;
    the README as written links into docs/ (docs/results.md) and to files the site does not hold, which a plain include
    would leave broken."""
    hook = readme_hook()
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    written = LINK.findall(readme)
    assert any(t.startswith("docs/results.md") for t in written) and "LICENSE" in written
    page = hook.readme_markdown(ROOT)
    targets = LINK.findall(page)
    assert len(targets) == len([t for t in written if t.startswith(("docs/", "http"))])
    for target in targets:
        if target.startswith(("http://", "https://")):
            continue
        file, _, anchor = target.partition("#")
        assert not file.startswith(("docs/", "../")) and (DOCS / file).is_file(), target
        if anchor:
            assert anchor in _anchors(DOCS / file), target
    assert "[`docs/`](README.md)" in page  # docs/README.md is the site's home
    assert "protocol in hardware/README.md)" in page and "MIT (LICENSE)." in page  # files the site does not hold


def test_a_docs_page_s_link_out_of_docs_lands_on_the_site():
    hook = readme_hook()
    text = "[README](../README.md#layout), [model](model.md#qp-filter), ![f](figures/demo_force.png), [up](../LICENSE)"
    assert hook.rewrite_links(text, "docs") == (f"[README]({hook.PAGE}#layout), [model](model.md#qp-filter), "
                                                "![f](figures/demo_force.png), up")
    assert hook.rewrite_links("[README](../../README.md)", "docs/sub") == f"[README](../{hook.PAGE})"
    assert hook.rewrite_links("[a](https://example.org/a/b.md) [b](#here)", "") == \
        "[a](https://example.org/a/b.md) [b](#here)"


HISTORY = {  # what belongs in CHANGELOG.md, not on a user page
    "a commit id": re.compile(r"\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}\b"),
    "an issue number": re.compile(r"\bissues? #?\d+|(?<![\w&/])#\d+\b", re.I),
    "a date": re.compile(r"\b20\d\d-[01]\d(-[0-3]\d)?\b"),
    "a time of day": re.compile(r"\b\d\d:\d\d\b(–\d\d:\d\d)? UTC"),
    "a work session": re.compile(r"\b(today|yesterday|(this|that|these|two|other|the|same) sessions?)\b", re.I),
}


def user_pages() -> list[Path]:
    return [ROOT / "README.md", *sorted(DOCS.glob("*.md"))]


def history_in(text: str) -> list[tuple[int, str, str]]:
    """(line number, kind, match) of every passage of HISTORY in `text`."""
    return [(number, kind, match.group(0)) for number, line in enumerate(text.splitlines(), start=1)
            for kind, pattern in HISTORY.items() for match in pattern.finditer(line)]


def test_the_history_scan_finds_what_it_looks_for():
    found = history_in("fixed in 84df02c (issue 36, #12), measured 2026-12-06 and 2026-11, 12:01–12:15 UTC, "
                       "in this session; today's path")
    assert [kind for _, kind, _ in found] == ["a commit id", "an issue number", "an issue number", "a date", "a date",
                                              "a time of day", "a work session", "a work session"]
    assert history_in("1e300, 3f2a..., float64, [x](results.md#contact-tasks), start time (UTC), 2.8 s, 12 000") == []


def test_user_pages_carry_no_history():
    """README.md and docs/*.md say what is, not when or in which change it came (CHANGELOG.md)."""
    found = [(page.relative_to(ROOT).as_posix(), *hit) for page in user_pages()
             for hit in history_in(page.read_text(encoding="utf-8"))]
    assert found == []
