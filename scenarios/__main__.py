"""Command line: `python -m scenarios --list` and `python -m scenarios NAME --out DIR [--param value ...]`."""

from __future__ import annotations

import argparse
import sys
import typing
from pathlib import Path

from scenarios import Scenario, get, registry
from softcbf_mj.runio import OutputDirError, prepare_out_dir

_TRUE = {"1", "true", "yes", "on"}
_FALSE = {"0", "false", "no", "off"}


def _parse_bool(text: str) -> bool:
    low = text.strip().lower()
    if low in _TRUE:
        return True
    if low in _FALSE:
        return False
    raise ValueError(f"expected one of {sorted(_TRUE | _FALSE)}, got {text!r}")


def _converter(annotation: object):
    if annotation is bool:
        return _parse_bool
    if annotation in (int, float, str):
        return annotation
    raise TypeError(f"scenario parameter type {annotation!r} is not supported on the command line")


def _describe(scenario: Scenario) -> str:
    hints = typing.get_type_hints(scenario.run)
    lines = [f"{scenario.name}: {scenario.description}"]
    for name, p in scenario.parameters().items():
        lines.append(f"    --{name.replace('_', '-')} {hints[name].__name__} (default {p.default!r})")
    return "\n".join(lines)


def _parse_params(scenario: Scenario, tokens: list[str]) -> dict[str, object]:
    hints = typing.get_type_hints(scenario.run)
    params = scenario.parameters()
    parser = argparse.ArgumentParser(prog=f"python -m scenarios {scenario.name}", add_help=False)
    for name, p in params.items():
        convert = _converter(hints[name])

        def typed(text: str, _name: str = name, _convert=convert) -> object:
            try:
                return _convert(text)
            except ValueError as exc:
                raise argparse.ArgumentTypeError(f"--{_name.replace('_', '-')}: {exc}") from None

        typed.__name__ = hints[name].__name__
        parser.add_argument(f"--{name.replace('_', '-')}", dest=name, type=typed, default=p.default)
    known, unknown = parser.parse_known_args(tokens)
    if unknown:
        valid = ", ".join(f"--{n.replace('_', '-')}" for n in params)
        raise ValueError(f"unknown parameter(s) {' '.join(unknown)} for scenario {scenario.name}; valid: {valid}")
    return vars(known)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m scenarios", description="Run a registered softcbf-mj scenario.")
    parser.add_argument("name", nargs="?", help="scenario name (see --list)")
    parser.add_argument("--list", action="store_true", help="list scenarios with their parameters")
    parser.add_argument("--out", type=Path, help="output folder (refused if it exists and is not empty)")
    parser.add_argument("--overwrite", action="store_true", help="replace the contents of an existing --out folder")
    args, rest = parser.parse_known_args(argv)

    if args.list:
        print("\n".join(_describe(s) for s in registry().values()))
        return 0
    if not args.name:
        parser.error("give a scenario name or --list")
    try:
        scenario = get(args.name)
    except KeyError as exc:
        parser.error(exc.args[0])
    try:
        params = _parse_params(scenario, rest)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.out is None:
        parser.error("--out DIR is required to run a scenario")
    try:
        out_dir = prepare_out_dir(args.out, overwrite=args.overwrite)
    except OutputDirError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        scenario.run(out_dir, **params)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"\ninterrupted: finished runs are in {out_dir}", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
