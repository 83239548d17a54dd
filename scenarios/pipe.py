"""A command line whose reader went away: `softcbf list | head` ends quietly.

When the process at the other end of a pipe exits (`head` after its ten lines), the next
write to stdout fails with EPIPE; Python ignores SIGPIPE and raises BrokenPipeError, from a
`print` or from the final flush of stdout's buffer at exit, where it would print a traceback
(or "Exception ignored ...") and exit 1 or 120. `quiet_on_closed_pipe(command)` runs
`command()` and flushes stdout before it returns, so that the error surfaces there; it then
points stdout at os.devnull (the interpreter's own flush at exit then writes nowhere) and
returns `CLOSED_PIPE` = 141 = 128 + SIGPIPE, the status a shell reports for a program that
SIGPIPE ended (`yes | head`: `set -o pipefail` sees the truncated output as such), with
nothing on stderr. The recipe is the one the Python documentation gives (signal module, "Note
on SIGPIPE"). A `SystemExit` (argparse's `--help`) passes through once its output is flushed.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable

CLOSED_PIPE = 141  # 128 + SIGPIPE (13)


def quiet_on_closed_pipe(command: Callable[[], int]) -> int:
    """`command()`'s exit code with stdout flushed, or CLOSED_PIPE, silently, when stdout's reader has gone (module
    docstring)."""
    try:
        try:
            return command()
        finally:
            sys.stdout.flush()
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
        return CLOSED_PIPE
