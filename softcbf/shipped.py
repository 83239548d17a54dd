"""The files the project ships for users, by name: the study definitions (studies/*.toml), the hardware mode's
configurations (examples/hardware_*.toml) and the examples (examples/*.py, *.toml, *.json).

Where they are. In a checkout they are the repository's own folders; an installed wheel carries the same files
under `softcbf_files/` beside the packages (pyproject.toml's package-data: its patterns are `SHIPPED`'s, which
tests/test_packaging.py checks against a built wheel). `vocabulary.project_files` names both places; the wheel's
copy is taken when it is there (an installed package), the checkout's otherwise, so that a stray top-level
`examples/` folder of another package in site-packages is never read as ours.

By name. A command that takes a file (`softcbf study run|falsify FILE`, `softcbf hardware CONFIG`) takes it through
`resolve(kind, spec)`:
  1. `spec` is an existing path: that file, as given (a user's own file always wins);
  2. a bare name of a shipped file of that kind, with or without its suffix (`mismatch_box_contact`,
     `hardware_emulated.toml`): the shipped file;
  3. a path as the repository spells it (`studies/mismatch_box_contact.toml`, `examples/hardware_emulated.toml`:
     the README's commands) that is not in the working folder: the shipped file of that path, so the README's
     commands run unchanged outside the checkout;
  4. otherwise `UnknownShipped` (a ValueError): one line naming the spec, the closest shipped names
     (`controllers.registry.did_you_mean`) and all of them.
Only the kinds' own files resolve: a study name never finds a hardware configuration, nor a robot file.

Copied out. `copy_examples(dest, overwrite)` (`softcbf examples DIR`) writes every shipped file into DIR in the
repository's layout (DIR/examples/, DIR/studies/), so that, from DIR, the paths the files name inside them
(a study's `filter = "examples/clip_filter.py:ClipFilter"`, relative to the working folder) and the README's
commands hold. It refuses, before writing anything, when one of those files is already in DIR, unless `overwrite`.

Mount: `register_command("examples", HELP, add_arguments, run_command)` in softcbf/cli.py (lazily, as the others).
"""

from __future__ import annotations

import argparse
import shutil
from dataclasses import dataclass
from pathlib import Path

from controllers.registry import did_you_mean
from scenarios.run import UsageError
from vocabulary.project_files import INSTALLED, ROOT

HELP = "copy the shipped examples, studies and hardware configurations into a folder (its examples/ and studies/)"

# The shipped folders and their files' patterns: the wheel's package-data (pyproject.toml) holds the same.
SHIPPED = {"examples": ("*.py", "*.toml", "*.json"), "studies": ("*.toml",)}


@dataclass(frozen=True)
class Kind:
    """A kind of file that commands take by name: `noun` in messages, found as `folder`/`pattern`."""

    noun: str
    folder: str
    pattern: str


KINDS = {"study": Kind("study", "studies", "*.toml"),
         "hardware": Kind("hardware configuration", "examples", "hardware_*.toml")}


class UnknownShipped(ValueError):
    """A file spec that is neither a file nor a shipped name (one line: `resolve`)."""


class ExamplesExist(ValueError):
    """`copy_examples` without overwrite into a folder that already holds shipped files."""


def shipped_root() -> Path:
    """The folder that holds studies/ and examples/: the installed wheel's softcbf_files/, else the checkout."""
    return INSTALLED if INSTALLED.is_dir() else ROOT


def shipped_files() -> list[Path]:
    """Every shipped file, relative to `shipped_root()` (examples/..., studies/...), sorted."""
    root = shipped_root()
    found = {path.relative_to(root) for folder, patterns in SHIPPED.items() for pattern in patterns
             for path in (root / folder).glob(pattern) if path.is_file()}
    return sorted(found)


def shipped_names(kind: str) -> dict[str, Path]:
    """{name: file} of the shipped files of `kind` ('study', 'hardware'), by name (the file's stem), sorted."""
    spec = KINDS[kind]
    folder = shipped_root() / spec.folder
    return {path.stem: path for path in sorted(folder.glob(spec.pattern)) if path.is_file()}


def resolve(kind: str, spec: str | Path) -> Path:
    """The file `spec` names for a command taking a `kind` file (module docstring: path, name, repository path)."""
    path = Path(spec)
    if path.exists():
        return path
    names = shipped_names(kind)
    folder = KINDS[kind].folder
    text = path.as_posix()
    suffix = Path(KINDS[kind].pattern).suffix
    for name in (text, text.removesuffix(suffix)):
        if name in names:
            return names[name]
    if path.parent == Path(folder) and path.stem in names and path.suffix == suffix:
        return names[path.stem]  # the repository's path of a shipped file, run outside the checkout
    noun = KINDS[kind].noun
    shown = ", ".join(names) or "none"
    raise UnknownShipped(f"{noun} {text!r} is neither a file nor a shipped {noun}"
                         f"{did_you_mean(path.stem, names)}; shipped: {shown} (softcbf examples DIR copies them out)")


def copy_examples(dest: str | Path, overwrite: bool = False) -> list[Path]:
    """Copy every shipped file into `dest` in the repository's layout; the files written, relative to `dest`.
    ExamplesExist (nothing written) when one is already there and not `overwrite`."""
    dest = Path(dest)
    files = shipped_files()
    if dest.exists() and not dest.is_dir():
        raise ExamplesExist(f"{dest} is a file, not a folder")
    present = [f for f in files if (dest / f).exists()]
    if present and not overwrite:
        raise ExamplesExist(f"{dest} already holds {len(present)} of the {len(files)} shipped files "
                            f"(e.g. {present[0].as_posix()}); --overwrite replaces them")
    root = shipped_root()
    for relative in files:
        (dest / relative).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(root / relative, dest / relative)
    return files


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dir", type=Path, help="folder to copy into (made if missing)")
    parser.add_argument("--overwrite", action="store_true", help="replace shipped files already in DIR")


def run_command(args: argparse.Namespace, extra: list[str]) -> int:
    """Handler of `softcbf examples DIR [--overwrite]`: 0, or UsageError (exit 2) when refused or not writable."""
    try:
        files = copy_examples(args.dir, args.overwrite)
    except ExamplesExist as exc:
        raise UsageError(str(exc)) from None
    except OSError as exc:
        raise UsageError(f"cannot write {args.dir}: {exc.strerror or exc}") from None
    print(f"copied {len(files)} shipped files into {args.dir} (examples/, studies/); each says in its first lines "
          f"how to run it, from {args.dir}, e.g.:")
    print(f"  softcbf study run studies/NAME.toml --out runs/NAME    NAME: {', '.join(shipped_names('study'))}")
    for name in shipped_names("hardware"):
        print(f"  softcbf hardware examples/{name}.toml")
    return 0
