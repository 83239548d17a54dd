"""Packaging: the docs site builds with --strict (a broken link fails), and `python -m build` makes an
sdist and a wheel whose wheel, installed alone into a fresh environment, runs `softcbf list` and a short run, finds
the shipped studies and hardware configuration by name and copies the shipped files out (`softcbf examples`).
scripts/wheel_smoke.sh (CI) does the same with the newest allowed dependencies from the package index.

The fresh environment's commands, its pip install included, run without PYTHONPATH: a PYTHONPATH naming the checkout
(as a worktree's test run sets it) comes before site-packages on sys.path, so pip found the checkout's softcbf-mj
already there and installed nothing, and the commands imported the checkout instead of the wheel.

Marked `packaging` (deselect with `-m "not packaging"`); about 15 s on the project's 2-core machine."""

from __future__ import annotations

import shutil
import subprocess
import sys
import sysconfig
import os
import tarfile
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
pytestmark = pytest.mark.packaging


def mkdocs(config: Path, site: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / "mkdocs"), "build", "--strict", "-f", str(config), "-d", str(site)],
                          capture_output=True, text=True, timeout=300)


def test_docs_site_builds_strictly_and_a_broken_link_fails(tmp_path):
    result = mkdocs(ROOT / "mkdocs.yml", tmp_path / "site")
    assert result.returncode == 0, result.stderr[-3000:]
    assert (tmp_path / "site" / "environment" / "index.html").is_file()
    assert (tmp_path / "site" / "figures" / "shield_cem.png").is_file()
    home = (tmp_path / "site" / "index.html").read_text(encoding="utf-8")
    assert 'href="getting-started/"' in home and 'src="figures/demo_force.png"' in home
    readme = (tmp_path / "site" / "project-readme" / "index.html").read_text(encoding="utf-8")  # the hook's page
    assert 'href="../results/#contact-tasks"' in readme and not (tmp_path / "site" / "hooks").exists()
    broken = tmp_path / "broken"
    shutil.copytree(ROOT / "docs", broken / "docs")
    shutil.copy(ROOT / "mkdocs.yml", broken / "mkdocs.yml")
    shutil.copy(ROOT / "README.md", broken / "README.md")  # the site's README page
    page = broken / "docs" / "environment.md"
    page.write_text(page.read_text(encoding="utf-8") + "\nSee [nowhere](no-such-page.md).\n", encoding="utf-8")
    result = mkdocs(broken / "mkdocs.yml", tmp_path / "broken_site")
    assert result.returncode != 0 and "no-such-page.md" in result.stderr


def test_sdist_and_wheel_build_and_the_wheel_runs_alone(tmp_path):
    dist = tmp_path / "dist"
    result = subprocess.run([sys.executable, "-m", "build", "--no-isolation", "--outdir", str(dist), str(ROOT)],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    (sdist,), (wheel,) = sorted(dist.glob("*.tar.gz")), sorted(dist.glob("*.whl"))
    with tarfile.open(sdist) as archive:
        names = archive.getnames()
    assert any(n.endswith("/pyproject.toml") for n in names) and any(n.endswith("/softcbf_mj/env/presets.py") for n in names)
    with zipfile.ZipFile(wheel) as archive:
        assert "softcbf/cli.py" in archive.namelist() and "softcbf_mj/env/presets.py" in archive.namelist()
    # A fresh environment with only the wheel (no editable checkout); its dependencies come from this environment's
    # site-packages through a .pth file (appended after the wheel's own, so the wheel's modules win).
    alone = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120, env=alone)
    python = venv / "bin" / "python"
    purelib = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                             capture_output=True, text=True, check=True, env=alone).stdout.strip()
    Path(purelib, "dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n", encoding="utf-8")
    install = subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "-q", "--no-deps", str(wheel)],
                             capture_output=True, text=True, timeout=300, env=alone)
    assert install.returncode == 0, install.stderr[-3000:]
    work = tmp_path / "elsewhere"  # not the checkout: nothing of it on sys.path
    work.mkdir()
    where = subprocess.run([str(python), "-c", "import softcbf_mj, softcbf, scenarios; print(softcbf_mj.__file__)"],
                           cwd=work, capture_output=True, text=True, timeout=120, env=alone)
    assert where.returncode == 0 and where.stdout.strip().startswith(purelib), (where.stdout, where.stderr)
    listing = subprocess.run([str(venv / "bin" / "softcbf"), "list"], cwd=work, capture_output=True, text=True, timeout=120,
                             env=alone)
    assert listing.returncode == 0, listing.stderr[-3000:]
    assert "paper_sim" in listing.stdout and "e-erg" in listing.stdout
    run = subprocess.run([str(venv / "bin" / "softcbf"), "run", "paper_sim", "--duration", "0.2", "--progress", "false",
                          "--robot", "hardware-like", "--out", str(work / "run")],
                         cwd=work, capture_output=True, text=True, timeout=300, env=alone)
    assert run.returncode == 0, run.stderr[-3000:]
    assert (work / "run" / "summary.json").is_file()
    # The data files code reads at run time (robot presets above, the bench's box and emulator config) come with it.
    files = subprocess.run([str(python), "-c", "from softcbf.bench import EMULATOR_CONFIG; "
                            "from softcbf.study.worst_found import BOX_FILE, settings; "
                            "print(EMULATOR_CONFIG); print(BOX_FILE); print(settings(1)['box_file'])"],
                           cwd=work, capture_output=True, text=True, timeout=120, env=alone)
    assert files.returncode == 0, files.stderr[-3000:]
    emulator, box, shown = files.stdout.split()
    assert emulator.startswith(purelib) and box.startswith(purelib), files.stdout
    assert shown == "studies/mismatch_box_contact.toml"
    # The files shipped for users (softcbf.shipped.SHIPPED, the checkout's) are the wheel's softcbf_files/, reachable by
    # name from outside the checkout, and `softcbf examples DIR` copies them out.
    from softcbf.shipped import shipped_files

    with zipfile.ZipFile(wheel) as archive:
        in_wheel = {n.removeprefix("softcbf_files/") for n in archive.namelist()
                    if n.startswith(("softcbf_files/examples/", "softcbf_files/studies/"))}
    assert in_wheel == {p.as_posix() for p in shipped_files()}
    names = subprocess.run([str(python), "-c", "from softcbf.shipped import resolve; "
                            "print(resolve('study', 'mismatch_box_contact')); print(resolve('hardware', 'hardware_emulated')); "
                            "print(resolve('study', 'studies/paper_low_plate_corner.toml'))"],
                           cwd=work, capture_output=True, text=True, timeout=120)
    assert names.returncode == 0, names.stderr[-3000:]
    assert all(line.startswith(f"{purelib}/softcbf_files/") for line in names.stdout.split()), names.stdout
    bad = subprocess.run([str(venv / "bin" / "softcbf"), "study", "run", "mismatch_box_contat", "--out", str(work / "s")],
                         cwd=work, capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "did you mean 'mismatch_box_contact'" in bad.stderr and len(bad.stderr.splitlines()) == 1
    copied = subprocess.run([str(venv / "bin" / "softcbf"), "examples", str(work / "mine")],
                            cwd=work, capture_output=True, text=True, timeout=120)
    assert copied.returncode == 0, copied.stderr[-3000:]
    assert sorted(p.relative_to(work / "mine").as_posix() for p in (work / "mine").rglob("*") if p.is_file()) == sorted(in_wheel)


def test_citation_file_names_this_version_and_the_paper():
    import tomllib

    import yaml

    citation = yaml.safe_load((ROOT / "CITATION.cff").read_text(encoding="utf-8"))
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert citation["cff-version"] == "1.2.0" and citation["type"] == "software"
    assert str(citation["version"]) == project["version"] and citation["license"] == project["license"]
    assert all(key in citation for key in ("message", "title", "authors"))
    (paper,) = citation["references"]
    assert paper["journal"] == "IEEE Robotics and Automation Letters" and paper["year"] == 2025
    assert "Control Barrier Functions" in paper["title"]
