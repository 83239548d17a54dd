"""Isolation mode (docs/safety-filter.md#what-a-filter-cannot-do-per-mode): the filter and the nominal controller run in a process of their own.

In-process, a filter is Python code in the testbed's interpreter: it can patch any module
(`closedloop.kernels`, numpy, the step itself), reach the step's arrays through `gc` and
change a frozen object with `object.__setattr__`. No check written in Python holds against
that. Isolation puts the user's code where it cannot reach the plant, the clip or the record:
a child process (a fresh interpreter, `python -c` started by subprocess: no memory shared with
the testbed, its working directory and sys.path those of the parent at start; not a
multiprocessing child, so a study's daemonic Dask worker may start one too) that is given
the filter and nominal specs, their parameters and a copy of the `FilterContext` (pickled
parent → child, each plug-in then given its own `FilterContext.copy` there, as in-process), builds them with the registry (`controllers.registry`) and serves calls.
The parent holds proxies (`IsolatedFilter`, `IsolatedBatchFilter`, `IsolatedNominal`) that the
control step (`closedloop.step`) receives in place of the user's objects; the step's admission,
clip, monitor and record run in the parent as in-process, on what the proxies return.

What comes back is never unpickled (a child could craft a pickle that runs code in the
parent). A reply is a fixed format (`encode`, `decode`): a 4-byte little-endian length, a JSON
header (status, strings, bools) and raw float64 buffers whose shapes the header lists; the
parent checks every field's type and the buffer's length, builds the `FilterOutput` (or
`BatchOutput`, or the nominal's (N,) array) and the step converts it as usual (`OutputCheck`).
The child converts a filter's return with the same `OutputCheck` first (so a return the contract
refuses is refused with the same message, as a fault of the "filter" call), and reads each
diagnostic once.

Faults. A child exception (any BaseException: SystemExit and KeyboardInterrupt included) comes
back as its type name, first line, the user code's file:line and the child's traceback text;
the proxy raises it in the parent as an `IsolatedError` subclass of that name (raised from a
frame at that file:line, so that the step's `FilterFault` names the user's code), and the step
records a filter fault (hold, then vent; the run's record kept). `ControllerInputError` (a
refused input) comes back as such and is re-raised as one. A child that dies (os._exit, a
signal), a reply that is not the format, or no reply within the deadline (`CALL_DEADLINE_S`;
`BUILD_DEADLINE_S` for the build and the first call, which may compile a filter's kernels) is
an `IsolatedProcessError`: the child is ended and every later call of its objects raises the
same error. Load-time faults (a bad spec, unknown parameters, a raising factory, a child that
ends while building) raise `PluginLoadError` (one line; the command exits 2).

Lifetime. The child is ended when its proxies are gone (a `weakref.finalize` of the `Host`: the
end of the run that built them), by `Host.close()`, and at the parent's exit (an atexit hook,
`_end_all`). Ending it closes the socket and, when
the child does not leave within `END_WAIT_S`, kills it (SIGKILL: a child that ignores SIGTERM
or hangs). The child leaves by `os._exit` when its pipe closes (threads the user started do
not keep it alive) and a watchdog thread ends it when its parent is gone (a parent killed by
SIGKILL runs no atexit). SIGINT is ignored in the child: Ctrl-C interrupts the parent, which
ends the child. Requests (parent → child) are pickled: the child trusts its parent.

Assumptions and limits. The child runs as the same user: isolation is a memory boundary, not
a sandbox. It can still read and write the user's files, kill the parent with a signal, or use
the network. `filter_us`
in isolated mode includes the round trip (what the step waited). The parent imports no user
module: a spec's checks and labels (a factory's `run_label`) run in an isolated process too
(`check_in_child`). The cost per call is measured by tools/bench_isolation.py
(docs/results.md#isolation).
"""

from __future__ import annotations

import atexit
import dataclasses
import hashlib
import json
import math
import os
import pickle
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
import traceback
import weakref
from collections.abc import Callable, Mapping, Sequence
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np

from closedloop.step import RESERVED_COLUMNS
from controllers.contract.diagnostics import DiagnosticLayout, FlatDiagnostics
from controllers.core.errors import ControllerInputError
from controllers.registry import PluginLoadError, build_filter, build_nominal
from controllers.contract.capabilities import Capabilities, CapabilityError, filter_capabilities
from controllers.contract.safety_filter import (DIAGNOSTIC_FLOATS_MAX, BatchOutput, Estimate, EstimateBatch, FilterContext,
                                       FilterOutput, OutputCheck, checked_batch_arrays, read_only, real_vector,
                                       reset_filter)

BUILD_DEADLINE_S = 300.0  # s: the child's start, the build and the first call (imports, compiled kernels)
CALL_DEADLINE_S = 60.0  # s: any later call; beyond it the child is ended and the call is a fault
END_WAIT_S = 1.0  # s: how long an ended child may take to leave before it is killed
MAX_REPLY_BYTES = 64 * 2**20  # a reply longer than this is a protocol fault
WATCHDOG_S = 0.2  # s: how often the child checks that its parent is alive
CHILD_MAIN = "import sys; from closedloop.isolation import serve; serve(int(sys.argv[1]))"  # the child's program
_LENGTH = struct.Struct("<I")
_KINDS = {"f": float, "b": bool}  # a reply array's kinds: float64 values, bools as 0.0/1.0


class IsolatedError(Exception):
    """An exception raised by user code in the isolated process; its subclass carries the child's type name."""


class IsolatedProcessError(Exception):
    """The isolated process died, did not answer within the deadline, or sent what the format does not allow."""


class ProtocolError(ValueError):
    """A reply that is not the fixed format (`decode`)."""


# --- the reply format (child → parent) ---------------------------------------------------------------------------

def encode(header: dict[str, Any], arrays: Sequence[np.ndarray] = ()) -> bytes:
    """A reply: `header` (JSON-serialisable; gains "arrays": each array's [shape, kind]) and `arrays` as
    float64 buffers (bool arrays as 0.0/1.0, kind "b")."""
    specs, buffers = [], []
    for array in arrays:
        array = np.asarray(array)
        specs.append(f'[[{",".join(map(str, array.shape))}],"{"b" if array.dtype == bool else "f"}"]')
        buffers.append(np.ascontiguousarray(array, dtype="<f8").tobytes())
    text = json.dumps(header)  # the header's own fields, then "arrays" written out (the same JSON, made faster)
    head = f'{text[:-1]}{", " if len(text) > 2 else ""}"arrays": [{",".join(specs)}]}}'.encode("utf-8")
    return _LENGTH.pack(len(head)) + head + b"".join(buffers)


def decode(data: bytes) -> tuple[dict[str, Any], list[np.ndarray]]:
    """A reply's header and arrays (new arrays the parent owns); ProtocolError for anything else.
    Nothing in `data` is executed: JSON and float64 buffers only."""
    try:
        (size,) = _LENGTH.unpack_from(data)
        header = json.loads(bytes(data[4:4 + size]).decode("utf-8"))
    except (struct.error, ValueError, RecursionError) as exc:
        raise ProtocolError(f"unreadable reply header ({type(exc).__name__})") from None
    if type(header) is not dict or type(header.get("arrays")) is not list:
        raise ProtocolError("a reply header must be an object with a list 'arrays'")
    specs, total = header["arrays"], 0
    for spec in specs:
        if (type(spec) is not list or len(spec) != 2 or type(spec[0]) is not list or len(spec[0]) > 2
                or not all(type(d) is int and 0 <= d <= 2**20 for d in spec[0]) or spec[1] not in _KINDS):
            raise ProtocolError(f"bad array spec {str(spec)[:80]}")
        total += math.prod(spec[0])
    if 4 + size + 8 * total != len(data):
        raise ProtocolError(f"a reply of {len(data)} bytes for a header of {size} and {total} floats")
    values = np.frombuffer(data, dtype="<f8", offset=4 + size).astype(float)  # one copy the parent owns
    arrays, start = [], 0
    for shape, kind in specs:
        count = math.prod(shape)
        array = values[start:start + count].reshape(shape)
        arrays.append(array != 0.0 if kind == "b" else array)
        start += count
    return header, arrays


def _text(header: Mapping[str, Any], key: str, limit: int = 100_000) -> str:
    value = header.get(key)
    if type(value) is not str or len(value) > limit:
        raise ProtocolError(f"reply field {key!r} must be a str")
    return value


# --- the parent's side ---------------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class Plan:
    """What the child builds: the context, the filters' and the nominals' (spec, parameters); `copies` (`isolate`)."""

    context: FilterContext
    filters: tuple[tuple[str, dict[str, object]], ...]
    nominals: tuple[tuple[str, dict[str, object]], ...]
    copies: int = 1


_LIVE: set[weakref.finalize] = set()  # the finalizers of the hosts started in this process


def _end_all() -> None:
    """At the parent's exit: end every isolated process still running."""
    for finalizer in list(_LIVE):
        finalizer()


atexit.register(_end_all)


def _ended(process: subprocess.Popen, conn: Connection) -> None:
    """End the child: close its socket (it leaves by os._exit), kill it if it is still there after END_WAIT_S."""
    try:
        conn.close()
    except OSError:
        pass
    try:
        process.wait(END_WAIT_S)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()


class Host:
    """One isolated process hosting filters and nominals (module docstring): start it, send requests, decode replies.

    `request(message)` sends a pickled message and returns the decoded reply of status "ok",
    raises ControllerInputError (status "refused"), the child's exception (status "error") or
    IsolatedProcessError (no reply, a dead child, a bad reply: the child is ended, and every later
    request raises the same error)."""

    def __init__(self, plan: Plan, deadline_s: float = CALL_DEADLINE_S,
                 build_deadline_s: float = BUILD_DEADLINE_S) -> None:
        ours, theirs = socket.socketpair()
        self.conn, child_fd = Connection(ours.detach()), theirs.detach()
        root = str(Path(__file__).resolve().parents[1])  # where `closedloop` is imported from
        path = os.pathsep.join([root, *filter(None, os.environ.get("PYTHONPATH", "").split(os.pathsep))])
        try:
            self.process = subprocess.Popen([sys.executable, "-c", CHILD_MAIN, str(child_fd)], pass_fds=(child_fd,),
                                            stdin=subprocess.DEVNULL, env={**os.environ, "PYTHONPATH": path})
        finally:
            os.close(child_fd)  # the child's end lives in the child only: its death is an EOF here
        self.pid = self.process.pid
        self.deadline_s, self.next_deadline_s = deadline_s, build_deadline_s
        self.failure: IsolatedProcessError | None = None
        self.seq = 0
        self._finalizer = weakref.finalize(self, _ended, self.process, self.conn)
        self.conn.send_bytes(pickle.dumps((list(sys.path), plan), protocol=pickle.HIGHEST_PROTOCOL))
        _LIVE.difference_update([f for f in _LIVE if not f.alive])
        _LIVE.add(self._finalizer)

    @property
    def alive(self) -> bool:
        return self.failure is None and self.process.poll() is None

    def close(self) -> None:
        """End the child now (module docstring: lifetime)."""
        if self.failure is None:
            self.failure = IsolatedProcessError("the isolated process was closed")
        self._finalizer()

    def _fail(self, message: str) -> IsolatedProcessError:
        self.failure = IsolatedProcessError(message)
        self._finalizer()
        return self.failure

    def _death(self) -> str:
        try:
            code = self.process.wait(END_WAIT_S)
        except subprocess.TimeoutExpired:
            return "the isolated process closed its socket"
        if code < 0:
            try:
                name = signal.Signals(-code).name
            except ValueError:
                name = str(-code)
            return f"the isolated process was killed by signal {name}"
        return f"the isolated process ended with exit code {code}"

    def request(self, message: tuple) -> tuple[dict[str, Any], list[np.ndarray]]:
        if self.failure is not None:
            raise self.failure
        self.seq += 1
        deadline, self.next_deadline_s = self.next_deadline_s, self.deadline_s
        try:
            self.conn.send_bytes(pickle.dumps((self.seq, *message), protocol=pickle.HIGHEST_PROTOCOL))
            if not self.conn.poll(deadline):
                raise self._fail(f"the isolated process gave no answer within {deadline:g} s and was ended")
            data = self.conn.recv_bytes(MAX_REPLY_BYTES)
        except (EOFError, BrokenPipeError, ConnectionResetError):
            raise self._fail(self._death()) from None
        except OSError as exc:  # a message longer than MAX_REPLY_BYTES, a broken pipe
            raise self._fail(f"the isolated process sent an unreadable reply ({exc})") from None
        except BaseException:  # an interrupt while waiting: the child's state is unknown, it is ended
            self._fail("the isolated process was ended by an interrupt")
            raise
        try:
            header, arrays = decode(data)
            if header.get("seq") != self.seq:
                raise ProtocolError(f"reply {header.get('seq')!r} to request {self.seq}")
            status = header.get("status")
            if status == "ok":
                return header, arrays
            if status == "refused":
                error: BaseException = ControllerInputError(_text(header, "message"))
            elif status == "error":
                error = child_exception(_text(header, "type", 200), _text(header, "message"),
                                        _text(header, "traceback", 10**6))
                location = _text(header, "location", 10_000)
            else:
                raise ProtocolError(f"unknown reply status {str(status)[:40]!r}")
        except ProtocolError as exc:
            raise self._fail(f"the isolated process sent a reply that is not the format: {exc}") from None
        if status == "refused":
            raise error
        raise_at(error, location)


def child_exception(type_name: str, message: str, child_traceback: str) -> IsolatedError:
    """The parent's copy of a child's exception: an `IsolatedError` subclass named `type_name` (when it is an
    identifier), its str the child's message then the child's traceback (FilterFault keeps the first line)."""
    name = type_name if type_name.isidentifier() else "IsolatedError"
    cls = type(name, (IsolatedError,), {"__module__": "isolated"})
    return cls(f"{message}\n\n(raised in the isolated process)\n{child_traceback}")


def raise_at(error: BaseException, location: str) -> None:
    """Raise `error` from a frame at `location` ("file:line" of the user code in the child), so that
    the step's fault names that code (`closedloop.step.FilterFault.location`); the file is not read or run:
    its name and line only label the one-statement frame that raises."""
    where, _, line = location.rpartition(":")
    if where and "\0" not in where and line.isdigit() and 0 < int(line) < 10**7:
        code = compile("raise error", where, "exec").replace(co_firstlineno=int(line))
        exec(code, {"error": error})  # noqa: S102 - fixed code: raise `error`
    raise error


class IsolatedNominal:
    """A nominal controller hosted by `host` (its index `index`): `(t, q, qd) -> u_nom` (N,) hPa."""

    def __init__(self, host: Host, index: int) -> None:
        self.host, self.index = host, index

    def __call__(self, t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        header, arrays = self.host.request(("nominal", self.index, float(t), np.asarray(q, float).tolist(),
                                            np.asarray(qd, float).tolist()))
        if len(arrays) != 1:
            raise self.host._fail("a nominal reply must hold one array")
        return arrays[0]


class IsolatedFilter:
    """A safety filter hosted by `host` (its index `index`): `filter(estimate, u_nom)` and `reset(rows=None)`;
    `capabilities`: those the hosted filter declares (checked in the child at build; `filter_batch` is
    `IsolatedBatchFilter`'s). `layout`: the diagnostics' layout of the last reply that sent one (a reply sends it
    when it differs from the one before)."""

    def __init__(self, host: Host, index: int, capabilities: Capabilities) -> None:
        self.host, self.index, self.capabilities = host, index, capabilities
        self.layout: DiagnosticLayout | None = None

    def __call__(self, estimate: Estimate, u_nom: np.ndarray) -> FilterOutput:
        host = self.host
        header, arrays = host.request(("filter", self.index, float(estimate.t), float(estimate.t_capture),
                                       np.asarray(estimate.q, float).tolist(), np.asarray(estimate.qd, float).tolist(),
                                       np.asarray(u_nom, float).tolist()))
        try:
            if header.get("layout") is not None:
                self.layout = _layout(header["layout"])
            return _filter_output(header, arrays, self.layout)
        except (ProtocolError, ValueError, TypeError) as exc:
            raise host._fail(f"the isolated process sent a filter reply that is not the format: {exc}") from None

    def reset(self, rows: np.ndarray | None = None) -> None:
        self.host.request(("reset", self.index, None if rows is None else np.asarray(rows).tolist()))


class IsolatedBatchFilter(IsolatedFilter):
    """An `IsolatedFilter` whose hosted filter declares batched (the plug-in contract's `filter_batch`)."""

    def filter_batch(self, batch: EstimateBatch, u_nom: np.ndarray, rows: np.ndarray | None = None) -> BatchOutput:
        host = self.host
        header, arrays = host.request(("batch", self.index, np.array(batch.t, float), np.array(batch.t_capture, float),
                                       np.array(batch.q, float), np.array(batch.qd, float), np.array(u_nom, float),
                                       None if rows is None else np.asarray(rows).tolist()))
        actions = header.get("actions")
        if (len(arrays) != 3 or type(actions) is not list or not all(type(a) is str and len(a) < 1000 for a in actions)):
            raise host._fail("the isolated process sent a filter_batch reply that is not the format")
        return BatchOutput(arrays[0], actions, arrays[1], arrays[2])


def _layout(entries: object) -> DiagnosticLayout | None:
    """A reply's diagnostics layout: [[key, shape, is_bool, unit], ...] (None: no diagnostics)."""
    if type(entries) is not list or len(entries) > DIAGNOSTIC_FLOATS_MAX:
        raise ProtocolError("a layout must be a list")
    shapes, units, booleans = {}, {}, set()
    for entry in entries:
        if (type(entry) is not list or len(entry) != 4 or type(entry[0]) is not str or type(entry[1]) is not list
                or not all(type(d) is int and 0 <= d <= DIAGNOSTIC_FLOATS_MAX for d in entry[1]) or len(entry[1]) > 2
                or type(entry[2]) is not bool or type(entry[3]) is not str or len(entry[0]) + len(entry[3]) > 2000):
            raise ProtocolError("a layout entry must be [key, shape, is_bool, unit]")
        shapes[entry[0]], units[entry[0]] = tuple(entry[1]), entry[3]
        if entry[2]:
            booleans.add(entry[0])
    return DiagnosticLayout(shapes, units, frozenset(booleans)) if shapes else None


def _filter_output(header: Mapping[str, Any], arrays: list[np.ndarray], layout: DiagnosticLayout | None) -> FilterOutput:
    """The FilterOutput of a filter reply: arrays u, rho_pred (shape ()) and the diagnostics' flat values in
    `layout` (`FlatDiagnostics`, as the paper filter returns them); action (str) and infeasible (bool) from the
    header."""
    if len(arrays) != 3 or arrays[1].shape != () or arrays[2].shape != ((0,) if layout is None else (layout.size,)):
        raise ProtocolError("a filter reply must hold u, rho_pred and the diagnostics' values in its layout")
    infeasible = header.get("infeasible")
    if type(infeasible) is not bool:
        raise ProtocolError("infeasible must be a bool")
    action, rho = _text(header, "action", 1000), float(arrays[1])
    if layout is None:
        return FilterOutput(arrays[0], action, infeasible, rho)
    return FilterOutput(arrays[0], action, infeasible, rho, FlatDiagnostics(layout, arrays[2].tolist()), layout.units)


def isolate(context: FilterContext, filters: Sequence[tuple[str, Mapping[str, object]]],
            nominals: Sequence[tuple[str, Mapping[str, object]]], copies: int = 1, deadline_s: float = CALL_DEADLINE_S,
            build_deadline_s: float = BUILD_DEADLINE_S) -> tuple[list[IsolatedFilter], list[IsolatedNominal]]:
    """Start one isolated process that builds `filters` and `nominals` ((registry spec, parameters) each,
    told a copy of `context`) and return their proxies, in order, each declaring what its hosted filter declares
    (`filter_capabilities`, read in the child; a batched one as an `IsolatedBatchFilter`). `copies` > 1 (one filter
    given): a batch's filters, the one filter when it declares batched, else `copies` independent ones (one history
    per simulation, as `run_batch_tuning` builds them in-process). The process ends when every proxy is gone (module
    docstring). A load-time fault (a bad spec or parameters, a raising factory, a filter that lacks a capability it
    declares, a child that ends while building) raises PluginLoadError."""
    if copies > 1 and len(filters) != 1:
        raise ValueError(f"copies = {copies} needs one filter, got {len(filters)}")
    plan = Plan(context.copy(), tuple((spec, dict(params)) for spec, params in filters),
                tuple((spec, dict(params)) for spec, params in nominals), copies)
    host = Host(plan, deadline_s, build_deadline_s)
    host.next_deadline_s = build_deadline_s
    try:
        header, _ = host.request(("built",))
    except (IsolatedError, IsolatedProcessError) as exc:
        host.close()
        text = str(exc).strip().splitlines()
        line, name = text[0] if text else "", type(exc).__name__
        raise PluginLoadError(line if name in ("PluginLoadError", "ValueError") else
                              f"the isolated filter's build failed: {name}: {line}") from None
    host.next_deadline_s = build_deadline_s  # the first call may compile the filter's kernels
    try:
        declared = _capabilities(header.get("filters"), (len(filters), copies))
    except (ProtocolError, CapabilityError):
        host.close()
        raise PluginLoadError("the isolated process answered its build with a reply that is not the format") from None
    proxies = [(IsolatedBatchFilter if capabilities.batched else IsolatedFilter)(host, i, capabilities)
               for i, capabilities in enumerate(declared)]
    return proxies, [IsolatedNominal(host, i) for i in range(len(nominals))]


CAPABILITY_NAMES = tuple(f.name for f in dataclasses.fields(Capabilities))  # a build reply's entries, in this order


def _capabilities(entries: object, counts: tuple[int, ...]) -> list[Capabilities]:
    """A build reply's capabilities, one list of bools (CAPABILITY_NAMES' order) per hosted filter, `counts`
    the numbers of filters it may hold; ProtocolError (or CapabilityError) for anything else."""
    if type(entries) is not list or len(entries) not in counts:
        raise ProtocolError("the filters' capabilities must be a list of one entry per filter")
    if not all(type(e) is list and len(e) == len(CAPABILITY_NAMES) and all(type(v) is bool for v in e)
               for e in entries):
        raise ProtocolError(f"a filter's capabilities must be {len(CAPABILITY_NAMES)} bools")
    return [Capabilities(*entry) for entry in entries]


# --- the parent's checks of a spec (no user module imported in the parent) ---------------------------------------

_CHECKED: dict[tuple, tuple[str, ...]] = {}


def _digest(spec: str) -> str | None:
    """The sha1 of the Python file a FILE.py:Factory spec names (None: a built-in or package spec, or no file)."""
    where = spec.strip().rpartition(":")[0]
    try:
        return hashlib.sha1(Path(where).read_bytes()).hexdigest() if where.endswith(".py") else None
    except OSError:
        return None


def check_in_child(check: Callable[..., Sequence[str]], *args: Any, deadline_s: float = BUILD_DEADLINE_S) -> tuple[str, ...]:
    """`check(*args)` run in an isolated process: the strings it returns (the runs' labels), or ValueError with
    its one-line refusal. For the checks of a spec that imports user modules (`scenarios.common.check_plugins`),
    which the parent then never imports. `check` and `args` must pickle; results are cached per arguments and
    per content of the Python files the args' specs name (a study builds one spec per sample)."""
    key = (getattr(check, "__qualname__", repr(check)), pickle.dumps(args),
           tuple(_digest(getattr(a, "name", "")) for a in args), os.getcwd())
    if key in _CHECKED:
        return _CHECKED[key]
    host = Host(Plan(None, (), ()), deadline_s, deadline_s)  # type: ignore[arg-type]
    try:
        header, _ = host.request(("check", check, args))
    except (IsolatedError, IsolatedProcessError) as exc:
        text = str(exc).strip().splitlines()
        raise ValueError(text[0] if text else type(exc).__name__) from None
    finally:
        host.close()
    labels = header.get("labels")
    if type(labels) is not list or not all(type(s) is str and len(s) < 10_000 for s in labels):
        raise ValueError("the isolated check answered with a reply that is not the format")
    _CHECKED[key] = tuple(labels)
    return _CHECKED[key]


# --- the child's side ------------------------------------------------------------------------------------------------

def _watchdog(parent: int) -> None:
    while True:
        time.sleep(WATCHDOG_S)
        if os.getppid() != parent:
            os._exit(0)


def _location(exc: BaseException) -> str:
    frames = traceback.extract_tb(exc.__traceback__)
    here = os.path.abspath(__file__)
    for frame in reversed(frames):
        if os.path.abspath(frame.filename) != here and "site-packages" not in frame.filename:
            return f"{frame.filename}:{frame.lineno}"
    return ""


def _error(seq: int, exc: BaseException) -> bytes:
    if isinstance(exc, ControllerInputError):
        return encode({"seq": seq, "status": "refused", "message": str(exc)[:10_000]})
    text = str(exc).strip().splitlines()
    return encode({"seq": seq, "status": "error", "type": type(exc).__name__, "message": text[0][:10_000] if text else "",
                   "location": _location(exc), "traceback": "".join(traceback.format_exception(exc))[-100_000:]})


class Served:
    """The child's objects (built from a `Plan`) and its handling of one request."""

    def __init__(self, plan: Plan) -> None:
        self.filters: list[Any] = []
        self.capabilities: list[Capabilities] = []  # what each filter declares, checked at build
        self.nominals: list[Any] = []
        self.build_error: BaseException | None = None
        self.layouts: dict[int, tuple] = {}  # filter index → (its FlatDiagnostics' layout, the layout last sent)
        self.checks: dict[int, OutputCheck] = {}  # filter index → its output check (as the step's, new at reset)
        if plan.context is None:  # a check-only child
            return
        context = plan.context  # each plug-in gets context.copy(): u_min, u_max read-only again (pickling drops the flag)
        self.n = context.robot.n_segments
        try:
            self.filters = [build_filter(spec, params, context.copy()) for spec, params in plan.filters]
            if plan.copies > 1 and not filter_capabilities(self.filters[0]).batched:
                self.filters += [build_filter(*plan.filters[0], context.copy()) for _ in range(plan.copies - 1)]
            self.capabilities = [filter_capabilities(f) for f in self.filters]
            self.nominals = [build_nominal(spec, params, context.copy()) for spec, params in plan.nominals]
        except BaseException as exc:  # noqa: BLE001 - reported to the parent as a load-time fault
            self.build_error = exc

    def built(self, seq: int) -> bytes:
        if self.build_error is not None:
            return _error(seq, self.build_error)
        declared = [[getattr(c, name) for name in CAPABILITY_NAMES] for c in self.capabilities]
        return encode({"seq": seq, "status": "ok", "filters": declared})

    def handle(self, seq: int, op: str, args: tuple) -> bytes:
        if op == "built":
            return self.built(seq)
        if op == "check":
            check, check_args = args
            return encode({"seq": seq, "status": "ok", "labels": [str(s) for s in check(*check_args)]})
        if op == "nominal":
            index, t, q, qd = args
            value = self.nominals[index](t, read_only(np.array(q)), read_only(np.array(qd)))
            return encode({"seq": seq, "status": "ok"}, [real_vector(value, self.n, "the nominal command")])
        if op == "filter":
            index, t, t_capture, q, qd, u_nom = args
            result = self.filters[index](Estimate(t, read_only(np.array(q)), read_only(np.array(qd)), t_capture),
                                         read_only(np.array(u_nom)))
            check = self.checks.get(index)
            if check is None:
                check = self.checks[index] = OutputCheck(self.n, RESERVED_COLUMNS)
            output = check(result)
            diagnostics = output.diagnostics
            if type(diagnostics) is FlatDiagnostics and diagnostics.layout is self.layouts.get(index, (None,))[0]:
                layout, flat = None, np.array(diagnostics.values, dtype=float)  # the parent has this layout
            else:
                layout, flat = flat_diagnostics(output)
                if layout == self.layouts.get(index, (None, None))[1]:
                    layout = None
                else:
                    self.layouts[index] = (diagnostics.layout if type(diagnostics) is FlatDiagnostics else None, layout)
            return encode({"seq": seq, "status": "ok", "action": output.action, "infeasible": output.infeasible,
                           "layout": layout}, [output.u, np.array(output.rho_pred), flat])
        if op == "batch":
            index, t, t_capture, q, qd, u_nom, rows = args
            safety_filter = self.filters[index]
            batch = EstimateBatch(read_only(t), read_only(q), read_only(qd), read_only(t_capture))
            if rows is not None and self.capabilities[index].rows:
                result = safety_filter.filter_batch(batch, read_only(u_nom), rows=read_only(np.array(rows)))
            else:
                result = safety_filter.filter_batch(batch, read_only(u_nom))
            u, actions, infeasible, rho = checked_batch_arrays(result, len(t), self.n)
            return encode({"seq": seq, "status": "ok", "actions": actions}, [u, infeasible, rho])
        if op == "reset":
            index, rows = args
            self.checks.pop(index, None)
            if rows is not None and self.capabilities[index].reset_rows:
                self.filters[index].reset(rows=read_only(np.array(rows)))
            else:
                reset_filter(self.filters[index])
            return encode({"seq": seq, "status": "ok"})
        raise ValueError(f"unknown request {op!r}")


def flat_diagnostics(output: FilterOutput) -> tuple[list, np.ndarray]:
    """A checked output's diagnostics, read once, as a reply's layout [[key, shape, is_bool, unit], ...] and
    their values in it (one float64 array; each key's values row-major)."""
    diagnostics = output.diagnostics
    if type(diagnostics) is FlatDiagnostics:
        layout = diagnostics.layout
        return ([[key, list(shape), key in layout.booleans, str(layout.units[key])] for key, shape in layout.shapes.items()],
                np.array(diagnostics.values, dtype=float))
    entries, values = [], []
    for key, value in diagnostics.items():
        array = np.asarray(value)
        entries.append([key, list(array.shape), array.dtype == bool, str(output.diagnostic_units[key])])
        values.append(array.astype(float).ravel())
    return entries, np.concatenate(values) if values else np.zeros(0)


def serve(fd: int) -> None:
    """The isolated process's main (module docstring): on the socket `fd`, take the parent's sys.path and the
    `Plan`, build it, then answer requests until the socket closes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_watchdog, args=(os.getppid(),), daemon=True).start()
    conn = Connection(fd)
    try:
        sys.path[:], plan = pickle.loads(conn.recv_bytes())
    except (EOFError, OSError):
        os._exit(0)
    served = Served(plan)
    while True:
        try:
            seq, op, *args = pickle.loads(conn.recv_bytes())
        except (EOFError, OSError):
            os._exit(0)  # the parent closed the pipe: leave now, whatever threads the user started
        except Exception:  # noqa: BLE001 - not a request of the parent's (something in this process wrote it)
            os._exit(1)
        try:
            reply = served.handle(seq, op, tuple(args))
        except BaseException as exc:  # noqa: BLE001 - SystemExit, KeyboardInterrupt: the parent's fault to record
            reply = _error(seq, exc)
        try:
            conn.send_bytes(reply)
        except (OSError, ValueError):
            os._exit(0)
