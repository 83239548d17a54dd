"""The packed layout of the batched safety monitor, shared by `closedloop.monitor` (which owns the arrays) and its
compiled RUN case `closedloop.kernels` (which reads and writes them): column indices and the codes of a row's action.
Plain integers, so that numba folds them as constants."""

NOT_STEPPED = -1  # `BatchDecision.action` of a row that was not stepped
PENDING = 3  # `closedloop.kernels.run_plain`'s action of a stepped row off the RUN case (`decide` then decides it)
CLOCK, HOLD_SINCE, LAST_RUN = 0, 1, 2  # the columns of `BatchSafetyMonitor.state` (B, 2 + N): s, s, then N hPa
HAS_RUN, LATCHED = 0, 1  # the columns of `BatchSafetyMonitor.bits` (B, 2) bool
