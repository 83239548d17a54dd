"""A module imported on its first attribute access (the standard library's `importlib.util.LazyLoader`).

`controllers.pcc_model` compiles its kernels with numba, whose import alone costs about
0.2 s of CPU; the modules that merely describe a filter (`softcbf list`, `softcbf run NAME
--help`, which import every built-in filter for its docstring and parameters) must not pay
it. They hold `pcc_model = lazy_module("controllers.pcc_model")` and call
`pcc_model.model_terms(...)`: the first attribute access runs the module, after which the
object is the ordinary module (attribute access at the usual cost). A module already
imported is returned as it is.
"""

from __future__ import annotations

import importlib.util
import sys
from types import ModuleType


def lazy_module(name: str) -> ModuleType:
    """The module `name`, executed when one of its attributes is first read (module docstring)."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.find_spec(name)
    if spec is None or spec.loader is None:
        raise ImportError(f"no module named {name!r}")
    loader = importlib.util.LazyLoader(spec.loader)
    spec.loader = loader
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    loader.exec_module(module)
    return module
