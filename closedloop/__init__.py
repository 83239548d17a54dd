"""The closed loop's controller side, shared by every clock (docs/safety-filter.md): numpy and two
compiled kernels (numba, loaded on the first step), no MuJoCo, no I/O (but the isolation mode's socket).

- `closedloop.step`: `BatchControlStep`, the one control step (estimate → nominal → filter →
  admission → safety monitor → command) for B runs at once, and `ControlStep`, its B = 1 case
  for one run, with their records `BatchStepRecord` and `StepRecord`;
- `closedloop.monitor`: `BatchSafetyMonitor`, the run → hold → vent state machine in (B, ...)
  arrays, and `SafetyMonitor`, its B = 1 case (both decide through `decide`);
- `closedloop.kernels`: the admission and the monitor's RUN case over the batch axis, compiled;
- `closedloop.record`: `Recorder`, the one recorder, and `TIMESERIES_UNITS`, the one table of units;
- `closedloop.isolation`: the isolation mode, the filter and the nominal in a process of their own
  (proxies the step calls in their place; `--isolate true`).

Layers: imports `controllers` only; `hardware`, `softcbf_mj` and above import it.
"""
