"""Each declared default is typed once in the product code: its one home, the vocabulary.

A setting's default lives in `vocabulary.settings` (`Setting.default`, `DEFAULT_OVERRIDES`); the
classes that need it elsewhere (`ArmModelConfig`, `FlexureParams`, `CameraTiming`, the
environment, the hardware file) read it from there. The paper's plate stiffness and force limit
are needed below the vocabulary (`controllers.model.safe_set.paper_safe_set`), so their home is
`controllers.model.paper_experiment`, which the vocabulary imports. The scan: every number literal
of the product packages (a negative one too) equal to a *distinctive* default (a mantissa of two
or more significant digits: 11.16, 0.16, 12.8, 1.23044e-3, -0.055, 1280; not 0, 1, 0.5, 80) must
appear exactly once, at its home.
"""

from __future__ import annotations

import ast
from pathlib import Path

from test_setting_defaults import DISTINCTIVE as DEFAULTS  # the distinctive declared defaults (one definition)

REPO = Path(__file__).resolve().parents[1]
PRODUCT = ("controllers", "perception", "closedloop", "vocabulary", "hardware", "softcbf_mj", "scenarios", "softcbf")
# A literal equal to a default by its own meaning (not that default): path → {value: why}. Each must still be found.
OWN_MEANING = {
    "perception/synthetic.py": {
        1280.0: "the synthetic test camera's own image (perception sits below the vocabulary)",
        720.0: "the synthetic test camera's own image (perception sits below the vocabulary)",
    },
}


def number_literals(source: str) -> list[tuple[float, int]]:
    """(value, line) of every number literal of `source`, a unary minus applied (`-0.055` is -0.055)."""
    tree = ast.parse(source)
    negated = {id(node.operand) for node in ast.walk(tree)
               if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub) and isinstance(node.operand, ast.Constant)}
    return [(-float(node.value) if id(node) in negated else float(node.value), node.lineno) for node in ast.walk(tree)
            if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) and not isinstance(node.value, bool)]


def occurrences(paths: list[Path], defaults: set[float], root: Path = REPO) -> dict[float, list[str]]:
    """Default value → "path:line" of each literal equal to it in `paths` (relative to `root`)."""
    found: dict[float, list[str]] = {}
    for path in paths:
        rel = path.relative_to(root).as_posix()
        for value, line in number_literals(path.read_text(encoding="utf-8")):
            if value in defaults:
                found.setdefault(value, []).append(f"{rel}:{line}")
    return found


def test_the_scan_sees_negative_and_positive_literals(tmp_path):
    source = tmp_path / "m.py"
    source.write_text("A = -0.055\nB = (1280, 720)\nC = 0.5\nD = 11.16 * 2\n", encoding="utf-8")
    hits = occurrences([source], {-0.055, 1280.0, 720.0, 11.16}, tmp_path)
    assert {value: [h.rsplit(":", 1)[1] for h in where] for value, where in hits.items()} == {
        -0.055: ["1"], 1280.0: ["2"], 720.0: ["2"], 11.16: ["4"]}


def test_each_declared_default_is_typed_once_in_the_product_code():
    assert {11.16, 0.16, 12.8, 1.23044e-3, -0.055, -0.205, 1280.0, 720.0} <= DEFAULTS
    paths = [p for package in PRODUCT for p in sorted((REPO / package).rglob("*.py"))]
    found, own = occurrences(paths, DEFAULTS), set()
    for value in found:
        kept = []
        for where in found[value]:
            path = where.rsplit(":", 1)[0]
            if value in OWN_MEANING.get(path, {}):
                own.add((path, value))
            else:
                kept.append(where)
        found[value] = kept
    repeated = {value: where for value, where in found.items() if len(where) > 1}
    assert not repeated, ("declared defaults typed more than once (read them from vocabulary.settings: "
                          f"setting(name).default, default(name, context)): {repeated}")
    missing = sorted(value for value in DEFAULTS if not found.get(value))
    assert not missing, f"defaults typed nowhere (the vocabulary is their home): {missing}"
    stale = {(path, value) for path, values in OWN_MEANING.items() for value in values} - own
    assert not stale, f"OWN_MEANING entries no module holds any more (remove them): {sorted(stale)}"
