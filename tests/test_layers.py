"""The architecture as a test: layers import only downwards, no private name crosses a module.

Layers, bottom to top (a package may import its own modules and lower layers only;
packages on one layer do not import each other):

    0  controllers, perception   the controller under test (numpy, QP solvers; `controllers.bounds`, a
                                 number's range and its check) / the camera pipeline (OpenCV)
    1  vocabulary, closedloop    the settings: names, units, ranges (`controllers.bounds`) and their check,
                                 standard library only / the one control step, safety monitor and recorder
    2  hardware                  the valve-board link and the hardware loop
    3  softcbf_mj                the MuJoCo testbed: plants, loops, recording, reports
    4  scenarios                 registered experiments
    5  softcbf                   the application layer: CLI, hardware CLI, studies

Every module of every package is parsed (ast), including imports inside functions, with
no exception: `python -m scenarios` (scenarios/__main__.py) runs `scenarios.run`, the
implementation `softcbf run` imports.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from controllers.filter import CBFFilter

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


def _imports(path: Path, name: str | None = None) -> list[tuple[str, list[str]]]:
    """(module imported, names taken from it) for every import statement of module `name`
    (default: the module at `path`), relative ones resolved."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = (name or _module_name(path)).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(alias.name, []) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[: len(package) - node.level + 1] + ([base] if base else []))
            out.append((base, [alias.name for alias in node.names]))
    return out


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
    bad.write_text("from softcbf_mj.loop import run_closed_loop\nfrom .qp import _dual_active_set\n", encoding="utf-8")
    imports = _imports(bad, "controllers.bad")
    assert imports == [("softcbf_mj.loop", ["run_closed_loop"]), ("controllers.qp", ["_dual_active_set"])]
    assert _violations("controllers", "controllers/bad.py", "controllers.bad", imports) == [
        "controllers/bad.py imports softcbf_mj.loop: layer softcbf_mj is not below controllers",
        "controllers/bad.py imports private name(s) ['_dual_active_set'] from controllers.qp"]


def test_controllers_exports_its_public_api():
    import controllers
    from controllers import pcc  # submodules still import as before

    assert controllers.__all__ and all(getattr(controllers, name) is not None for name in controllers.__all__)
    assert controllers.CBFFilter is CBFFilter and callable(pcc.tip_position)
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        controllers.nothing  # noqa: B018
