"""A real Ctrl-C or user code's own KeyboardInterrupt: the one test the fault policy asks (closedloop.step).

Python turns SIGINT into a KeyboardInterrupt raised wherever the main thread happens to be, so a
Ctrl-C often lands inside a filter's call; a filter can also `raise KeyboardInterrupt` itself (or
SystemExit, GeneratorExit, any BaseException). Only the first is an interrupt: the run stops as
after any Ctrl-C (its finished part kept, resumable). Everything else user code raises is a
filter fault (docs/safety-filter.md#the-plug-in-boundary-is-a-trust-boundary).

`watch()` tells them apart from then on: in the main thread, and only where Python's own handler
(`signal.default_int_handler`) is in place, it installs `interrupt_handler`, which does what that
handler does (raise KeyboardInterrupt) and keeps the exception it raised. `is_interrupt(exc)` is
then True for that exception, or for a KeyboardInterrupt raised while it was being handled (its
`__context__` chain holds it), and False for every other exception. Where SIGINT is ignored
(SIG_IGN) or ends the process (SIG_DFL), no KeyboardInterrupt is a Ctrl-C. Where another handler
is in place (such as the hardware loop's, or Python's own because `watch()` was never called from
the main thread) every KeyboardInterrupt counts as a real one: nothing that may be the user's
Ctrl-C is taken for a fault. The control step and the plug-in registry call `watch()` when they are built, the
command line when it starts.
"""

from __future__ import annotations

import signal
import threading

_RAISED: list[BaseException] = []  # the KeyboardInterrupt the handler raised last (one at most)


def interrupt_handler(signum: int, frame: object) -> None:
    """SIGINT's handler while watched: raise KeyboardInterrupt, as Python's own does, and keep it."""
    exc = KeyboardInterrupt()
    _RAISED[:] = [exc]
    raise exc


def watch() -> bool:
    """Install `interrupt_handler` where Python's own SIGINT handler is in place (main thread only);
    True when it is in place now."""
    if threading.current_thread() is threading.main_thread() and \
            signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, interrupt_handler)
    return signal.getsignal(signal.SIGINT) is interrupt_handler


def is_interrupt(exc: BaseException) -> bool:
    """Whether `exc`, raised by user code, is a real Ctrl-C (module docstring)."""
    if not isinstance(exc, KeyboardInterrupt):
        return False
    handler = signal.getsignal(signal.SIGINT)
    if handler in (signal.SIG_IGN, signal.SIG_DFL):
        return False  # SIGINT is ignored or ends the process: it raises nothing
    if handler is not interrupt_handler:
        return True  # no way to tell: taken as the user's Ctrl-C
    seen, depth = exc, 0
    while seen is not None and depth < 100:
        if _RAISED and seen is _RAISED[0]:
            return True
        seen, depth = seen.__context__, depth + 1
    return False
