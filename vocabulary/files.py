"""Reading a settings file: the one reader of run configurations and hardware configurations.

A settings file is TOML (`.toml`, tomllib) or JSON (`.json`), told apart by its suffix; its
top level must be a table. `read_settings_file(path, noun, error)` returns that table or
raises `error` (the caller's ValueError subclass) with a message that starts with `noun`
and the path and says what is wrong: no such file (plus `missing_hint`), another suffix,
or a parse error with its line and column.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import Any

SUFFIXES = (".toml", ".json")


def read_settings_file(path: str | Path, noun: str, error: type[ValueError] = ValueError,
                       missing_hint: str = "") -> dict[str, Any]:
    """The top-level table of the TOML or JSON file at `path` (module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise error(f"{noun} {path} does not exist{f' ({missing_hint})' if missing_hint else ''}")
    if path.suffix not in SUFFIXES:
        raise error(f"{noun} {path} must end in .toml or .json, got {path.suffix!r}")
    text = path.read_text(encoding="utf-8")
    try:
        data = tomllib.loads(text) if path.suffix == ".toml" else json.loads(text)
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        raise error(f"{noun} {path} is not valid {path.suffix[1:].upper()}: {exc}") from None
    if not isinstance(data, dict):
        raise error(f"{noun} {path} must hold a table of settings at its top level, got {type(data).__name__}")
    return data
