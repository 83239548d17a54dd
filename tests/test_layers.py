"""The architecture as a test: layers import only downwards, no private name crosses a module.

Layers, bottom to top (a package may import its own modules and lower layers only;
packages on one layer do not import each other):

    0  controllers, perception   the controller under test (numpy, QP solvers; `controllers.core.bounds`, a
                                 number's range and its check) / the camera pipeline (OpenCV)
    1  vocabulary, closedloop    the settings: names, units, ranges (`controllers.core.bounds`) and their check,
                                 standard library only / the one control step, safety monitor and recorder
    2  hardware                  the valve-board link and the hardware loop
    3  softcbf_mj                the MuJoCo testbed: plants, loops, recording, reports
    4  scenarios                 registered experiments
    5  softcbf                   the application layer: CLI, hardware CLI, studies

Every module of every package is parsed (ast), with no exception: every import node wherever it
stands (`ast.walk`: at the top, inside functions, methods, conditionals and `try`), and every
import by name in a string constant (`importlib.import_module("x")`, `import_module("x")`,
`lazy_module("x")`, `__import__("x")`: the module is imported all the same, only later).
`python -m scenarios` (scenarios/__main__.py) runs `scenarios.run`, the implementation
`softcbf run` imports.

Inside a package the same holds one level down. Its units are its subpackages (one unit each,
e.g. `controllers.governors`, `softcbf_mj.physics`, `softcbf.bench`) and its own modules (one unit
each); importing a package's `__init__` alone is no edge. The units import each other without a
cycle (a cycle is reported with one import per hop). The rooms of `controllers` and `softcbf_mj`
(`ROOMS`) are ordered, bottom to top, and a room imports only rooms below it:

    controllers  core < model < energy < contract < cbf < governors < nominal < registry
    softcbf_mj   outputs < physics < camera < loops < emulator < env

(the governors build on the contract, the model and the CBF; the environment composes the testbed).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from controllers.cbf.paper_filter import CBFFilter

REPO = Path(__file__).resolve().parents[1]
LAYERS = {"controllers": 0, "perception": 0, "vocabulary": 1, "closedloop": 1, "hardware": 2, "softcbf_mj": 3, "scenarios": 4,
          "softcbf": 5}
FORBIDDEN = {  # third-party modules a package must not import
    "vocabulary": ("numpy", "mujoco", "cv2", "rerun", "matplotlib"),
    "controllers": ("mujoco", "cv2", "rerun", "matplotlib"),
    "perception": ("mujoco", "rerun", "matplotlib"),
    "closedloop": ("mujoco", "cv2", "rerun", "matplotlib"),
    "hardware": ("mujoco", "rerun", "matplotlib"),
}


def _modules(package: str) -> list[Path]:
    return sorted((REPO / package).rglob("*.py"))


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


IMPORT_CALLS = ("import_module", "lazy_module", "__import__")  # f("module"): an import by name


def _imports(path: Path, name: str | None = None) -> list[tuple[str, list[str]]]:
    """(module imported, names taken from it) for every import of module `name` (default: the module at
    `path`): every import node wherever it stands, relative ones resolved, and every `IMPORT_CALLS` call
    whose first argument is a string constant (module docstring), in the order they stand."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = (name or _module_name(path)).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node, alias.name, []) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[: len(package) - node.level + 1] + ([base] if base else []))
            found.append((node, base, [alias.name for alias in node.names]))
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant) \
                and isinstance(node.args[0].value, str):
            called = node.func.attr if isinstance(node.func, ast.Attribute) else getattr(node.func, "id", None)
            if called in IMPORT_CALLS:
                found.append((node, node.args[0].value, []))
    return [(module, names) for _, module, names in sorted(found, key=lambda f: (f[0].lineno, f[0].col_offset))]


ALL = [(package, path) for package in LAYERS for path in _modules(package)]


def _violations(package: str, rel: str, module_name: str, imports: list[tuple[str, list[str]]]) -> list[str]:
    """What module `module_name` (file `rel`) of `package` breaks by its `imports`."""
    out = []
    for module, names in imports:
        top = module.split(".")[0]
        if top in LAYERS and top != package and LAYERS[top] >= LAYERS[package]:
            out.append(f"{rel} imports {module}: layer {top} is not below {package}")
        if top in FORBIDDEN.get(package, ()):
            out.append(f"{rel} imports {module}, which {package} must not use")
        private = [n for n in names if n.startswith("_") and not n.startswith("__")]
        if top in LAYERS and module != module_name and private:
            out.append(f"{rel} imports private name(s) {private} from {module}")
    return out


@pytest.mark.parametrize("package,path", ALL, ids=[str(p.relative_to(REPO)) for _, p in ALL])
def test_module_imports_only_downwards_and_no_private_names(package, path):
    assert _violations(package, str(path.relative_to(REPO)), _module_name(path), _imports(path)) == []


@pytest.mark.parametrize("package,path", ALL, ids=[str(p.relative_to(REPO)) for _, p in ALL])
def test_module_calls_no_private_attribute_of_another_module(package, path):
    """`module._name` where `module` is an imported project module (import x.y as m; m._f())."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    aliases = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] in LAYERS:
                    aliases[alias.asname or alias.name.split(".")[0]] = alias.name
        elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] in LAYERS:
            for alias in node.names:  # `from pkg import module`
                aliases.setdefault(alias.asname or alias.name, f"{node.module}.{alias.name}")
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases:
            attr = node.attr
            assert not (attr.startswith("_") and not attr.startswith("__")), (
                f"{path.relative_to(REPO)} uses private {node.value.id}.{attr} of {aliases[node.value.id]}")


def test_the_layer_test_sees_every_package_and_finds_an_upward_import(tmp_path):
    """The test can fail: an upward import in a module is reported."""
    assert {p.parts[len(REPO.parts)] for _, p in ALL} == set(LAYERS)
    bad = tmp_path / "bad.py"
    bad.write_text("from softcbf_mj.loops.loop import run_closed_loop\nfrom .qp import _dual_active_set\n", encoding="utf-8")
    imports = _imports(bad, "controllers.bad")
    assert imports == [("softcbf_mj.loops.loop", ["run_closed_loop"]), ("controllers.qp", ["_dual_active_set"])]
    assert _violations("controllers", "controllers/bad.py", "controllers.bad", imports) == [
        "controllers/bad.py imports softcbf_mj.loops.loop: layer softcbf_mj is not below controllers",
        "controllers/bad.py imports private name(s) ['_dual_active_set'] from controllers.qp"]


ROOMS = {  # module docstring: each package's rooms, bottom to top; a room imports only rooms below it
    "controllers": ("core", "model", "energy", "contract", "cbf", "governors", "nominal", "registry"),
    "softcbf_mj": ("outputs", "physics", "camera", "loops", "emulator", "env"),
}


def _targets(module: str, names: list[str]) -> list[str]:
    """The modules an import of `names` from `module` loads below a package's `__init__`: `module` itself, or,
    for `from package import name`, each name that is a module or subpackage of the package."""
    if "." in module:
        return [module]
    return [f"{module}.{n}" for n in names if (REPO / module / n).is_dir() or (REPO / module / f"{n}.py").is_file()]


def _unit(module: str) -> str | None:
    """The unit of `module` in its package (module docstring): `package.x` for its own module x or subpackage x;
    None for the package's `__init__` and for modules outside the project."""
    parts = module.split(".")
    return ".".join(parts[:2]) if parts[0] in LAYERS and len(parts) > 1 else None


def _unit_edges(modules: list[tuple[str, str, list[tuple[str, list[str]]]]]) -> dict[tuple[str, str], str]:
    """(unit, unit of the same package it imports) → the first import that makes the edge ("file imports module"),
    for modules given as (module name, file, its `_imports`)."""
    edges: dict[tuple[str, str], str] = {}
    for name, rel, imports in modules:
        source = _unit(name)
        for module, names in imports:
            for target in map(_unit, _targets(module, names)):
                if source and target and target != source and target.split(".")[0] == source.split(".")[0]:
                    edges.setdefault((source, target), f"{rel} imports {module}")
    return edges


def _unit_violations(edges: dict[tuple[str, str], str]) -> list[str]:
    """What the unit graph `edges` breaks: an import of a room not below the importing room (`ROOMS`), and each
    cycle (its edges, in order)."""
    def rank(unit: str) -> int:
        package, room = unit.split(".", 1)
        return ROOMS[package].index(room)

    out = [f"{example}: {target} is not below {source}" for (source, target), example in sorted(edges.items())
           if source.split(".")[0] in ROOMS and rank(target) >= rank(source)]
    graph: dict[str, set[str]] = {}
    for source, target in edges:
        graph.setdefault(source, set()).add(target)

    def reach(unit: str) -> set[str]:
        seen, todo = set(), [unit]
        while todo:
            for nxt in graph.get(todo.pop(), ()):
                if nxt not in seen:
                    seen.add(nxt)
                    todo.append(nxt)
        return seen

    reachable = {unit: reach(unit) for unit in graph}
    cycles = sorted({tuple(sorted(u for u in reachable if unit in reachable[u] and u in reachable[unit]))
                     for unit in reachable if unit in reachable[unit]})
    for cycle in cycles:
        hops = [example for (source, target), example in sorted(edges.items()) if source in cycle and target in cycle]
        out.append(f"{', '.join(cycle)} import each other: " + "; ".join(hops))
    return out


def test_units_of_each_package_import_each_other_without_a_cycle():
    """Inside a package (module docstring): no cycle between its subpackages and modules, and each room of
    `ROOMS` imports only the rooms below it; the rooms are exactly the package's subpackages and modules."""
    modules = [(_module_name(path), str(path.relative_to(REPO)), _imports(path)) for _, path in ALL]
    for package, rooms in ROOMS.items():
        here = {p.stem for p in (REPO / package).iterdir() if (p.suffix == ".py" and p.stem != "__init__")
                or (p / "__init__.py").is_file()}
        assert here == set(rooms), f"{package}: rooms {sorted(here)} against ROOMS {sorted(rooms)}"
    assert _unit_violations(_unit_edges(modules)) == []


def test_the_layer_test_finds_imports_inside_functions_and_by_name(tmp_path):
    """The test can fail on what stands inside a function: an import statement into the same layer, an import
    by name of a higher layer, an import of a higher room of the package, and a cycle between subpackages."""
    bad = tmp_path / "bad.py"
    bad.write_text("import importlib\n\n\ndef detect():\n    from controllers.model.pcc import tip_position\n\n\n"
                   "class Camera:\n    def start(self):\n        try:\n            importlib.import_module('softcbf_mj.loops.loop')\n"
                   "        except ImportError:\n            pass\n", encoding="utf-8")
    imports = _imports(bad, "perception.bad")
    assert imports == [("importlib", []), ("controllers.model.pcc", ["tip_position"]), ("softcbf_mj.loops.loop", [])]
    assert _violations("perception", "perception/bad.py", "perception.bad", imports) == [
        "perception/bad.py imports controllers.model.pcc: layer controllers is not below perception",
        "perception/bad.py imports softcbf_mj.loops.loop: layer softcbf_mj is not below perception"]
    flat = tmp_path / "flat.py"
    flat.write_text("def build():\n    box = lazy_module('controllers.governors.energy_governor.box')\n", encoding="utf-8")  # model < governors
    study = tmp_path / "tune.py"
    study.write_text("def force(run):\n    from softcbf.bench import steady_force_of_folder\n", encoding="utf-8")
    bench = tmp_path / "cases.py"
    bench.write_text("from softcbf.study.definition import Study\n", encoding="utf-8")
    edges = _unit_edges([("controllers.model.flat", "controllers/model/flat.py", _imports(flat, "controllers.model.flat")),
                         ("softcbf.study.tune", "softcbf/study/tune.py", _imports(study, "softcbf.study.tune")),
                         ("softcbf.bench.cases", "softcbf/bench/cases.py", _imports(bench, "softcbf.bench.cases"))])
    assert _unit_violations(edges) == [
        "controllers/model/flat.py imports controllers.governors.energy_governor.box: controllers.governors is not below "
        "controllers.model",
        "softcbf.bench, softcbf.study import each other: softcbf/bench/cases.py imports softcbf.study.definition; "
        "softcbf/study/tune.py imports softcbf.bench"]


def test_controllers_exports_its_public_api():
    import controllers
    from controllers.model import pcc  # modules import from their rooms

    assert controllers.__all__ and all(getattr(controllers, name) is not None for name in controllers.__all__)
    assert controllers.CBFFilter is CBFFilter and callable(pcc.tip_position)
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        controllers.nothing  # noqa: B018
