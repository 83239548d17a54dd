"""A module imported on its first attribute access, safely from any number of threads.

`controllers.model.pcc_model` compiles its kernels with numba, whose import alone costs about
0.2 s of CPU; the modules that merely describe a filter (`softcbf list`, `softcbf run NAME
--help`, which import every built-in filter for its docstring and parameters) must not pay
it. They hold `pcc_model = lazy_module("controllers.model.pcc_model")` and call
`pcc_model.model_terms(...)`: the first attribute access runs the module, after which the
object is the ordinary module (attribute access at the usual cost). A module already
imported is returned as it is.

Why not the standard library's `importlib.util.LazyLoader`: on Python 3.11 its module turns
into a plain module *before* its code has run, so a second thread that reads an attribute
meanwhile finds an empty module (AttributeError). A threaded Dask worker builds a filter in
two threads at once, which is that case. Here the load is serialised instead:

- The placeholder is a `DeferredModule`; every attribute read, write or deletion takes
  `LOAD_LOCK` (re-entrant), and the first one runs the module's code into the placeholder's
  own namespace with the module's ordinary loader. Only when that code has finished does
  the placeholder become a plain module; a thread that waited on the lock then finds the
  loaded module. Re-entrant reads from the loading thread (the loader reading
  `__name__` and `__dict__`, the module's code importing another deferred module or
  itself) see the namespace as it is so far, as an ordinary import would.
- One lock for every deferred module, not one per module: a deferred module whose code
  imports another (`controllers.energy.energy_kernels` imports `controllers.model.pcc_model`) nests in
  the same thread and cannot wait on a second thread in the opposite order. Assumed: no
  module imported by a deferred module's code reads a deferred module's attribute while a
  different thread is importing it (the modules deferred here import numpy, numba and
  plain parameter modules).
- A failed load re-raises its error and leaves the placeholder deferred: the next access
  runs the code again and raises again, instead of leaving a half-filled module behind.
- Registration (`lazy_module`) is serialised by `REGISTER_LOCK`, held only around the
  `sys.modules` check and insertion (the module's spec is found outside it), so two modules
  that defer the same name at the same time share one placeholder.
"""

from __future__ import annotations

import importlib.util
import sys
import threading
from types import ModuleType

LOAD_LOCK = threading.RLock()  # held while a deferred module's code runs (module docstring)
REGISTER_LOCK = threading.Lock()  # held around the sys.modules check and insertion in lazy_module
LOADING: set[str] = set()  # names whose code runs now, in the thread that holds LOAD_LOCK


def load_deferred(module: ModuleType) -> None:
    """Run a `DeferredModule`'s code once, under `LOAD_LOCK`, then make it a plain module (module docstring)."""
    with LOAD_LOCK:
        if type(module) is not DeferredModule:  # another thread loaded it while this one waited
            return
        name = ModuleType.__getattribute__(module, "__name__")
        if name in LOADING:  # a re-entrant read from the loading thread: the namespace as it is so far
            return
        LOADING.add(name)
        try:
            spec = ModuleType.__getattribute__(module, "__spec__")
            spec.loader.exec_module(module)
            module.__class__ = ModuleType
        finally:
            LOADING.discard(name)


class DeferredModule(ModuleType):
    """A registered module whose code has not run yet; any attribute access runs it first (`load_deferred`)."""

    def __getattribute__(self, attr: str):
        load_deferred(self)
        return ModuleType.__getattribute__(self, attr)

    def __setattr__(self, attr: str, value) -> None:
        load_deferred(self)
        ModuleType.__setattr__(self, attr, value)

    def __delattr__(self, attr: str) -> None:
        load_deferred(self)
        ModuleType.__delattr__(self, attr)


def lazy_module(name: str) -> ModuleType:
    """The module `name`, executed when one of its attributes is first read (module docstring)."""
    with REGISTER_LOCK:
        if name in sys.modules:
            return sys.modules[name]
    spec = importlib.util.find_spec(name)
    if spec is None or spec.loader is None:
        raise ImportError(f"no module named {name!r}")
    with REGISTER_LOCK:
        if name in sys.modules:  # registered by another thread meanwhile
            return sys.modules[name]
        module = importlib.util.module_from_spec(spec)
        module.__class__ = DeferredModule
        sys.modules[name] = module
        parent, _, child = name.rpartition(".")
        if parent:  # as an import does: `package.child` reads the module (find_spec imported the package)
            setattr(sys.modules[parent], child, module)
    return module
