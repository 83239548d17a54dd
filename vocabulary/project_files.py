"""The project's data files that code reads at run time: the robot presets (models/robots/*.json), the standard
mismatch box of the bench's falsification (studies/*.toml) and the emulator's hardware config
(examples/hardware_emulated.toml).

In a checkout they are the repository's own files. An installed wheel carries the same files under the
`softcbf_files` folder beside these packages (pyproject.toml maps models/robots, studies and examples there), so
`project_file("studies/mismatch_box_contact.toml")` finds them in either layout. A path that is in neither raises
FileNotFoundError naming both places."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]  # the checkout, or site-packages of an installed wheel
INSTALLED = ROOT / "softcbf_files"


def project_file(relative: str) -> Path:
    """The project's file at `relative` (a path as in the repository, e.g. 'models/robots/hardware_like.json')."""
    for base in (ROOT, INSTALLED):
        path = base / relative
        if path.is_file():
            return path
    raise FileNotFoundError(f"the project's file {relative!r} is neither in the checkout ({ROOT / relative}) nor "
                            f"in the installed package ({INSTALLED / relative})")


def shown(path: str | Path) -> str:
    """`path` as the repository names it ('studies/x.toml') where it is one of the project's files in either layout,
    else the resolved path: what bench.json records, the same for a checkout and an installed wheel."""
    resolved = Path(path).resolve()
    for base in (INSTALLED, ROOT):
        if resolved.is_relative_to(base):
            return resolved.relative_to(base).as_posix()
    return str(resolved)
