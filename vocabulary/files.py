"""Reading a settings file: the one reader of run configurations and hardware configurations.

A settings file is TOML (`.toml`, tomllib) or JSON (`.json`), told apart by its suffix; its
top level must be a table. `read_settings_file(path, noun, error)` returns that table or
raises `error` (the caller's ValueError subclass) with a message that starts with `noun`
and the path and says what is wrong: no such file (plus `missing_hint`), another suffix,
or a parse error with its line and column. A key given twice in one table is a parse error in
both formats (tomllib refuses it; JSON, which would keep the last, is read with
`unique_keys`), so a duplicate setting or filter parameter never wins silently.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import Any

SUFFIXES = (".toml", ".json")


def unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """A JSON object's (key, value) pairs as a dict; ValueError naming a key given twice (`json.loads`'s
    object_pairs_hook)."""
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"key {key!r} is given twice in one object ({out[key]!r}, then {value!r}); give it once")
        out[key] = value
    return out


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
        data = tomllib.loads(text) if path.suffix == ".toml" else json.loads(text, object_pairs_hook=unique_keys)
    except (tomllib.TOMLDecodeError, ValueError) as exc:  # json.JSONDecodeError and unique_keys' are ValueErrors
        raise error(f"{noun} {path} is not valid {path.suffix[1:].upper()}: {exc}") from None
    if not isinstance(data, dict):
        raise error(f"{noun} {path} must hold a table of settings at its top level, got {type(data).__name__}")
    return data
