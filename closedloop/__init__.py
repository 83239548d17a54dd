"""The closed loop's controller side, shared by every clock (docs/safety-filter.md): numpy only, no MuJoCo, no I/O.

- `closedloop.step`: `ControlStep`, the one control step (estimate → nominal → filter →
  admission → safety monitor → command) and its `StepRecord`; `BatchControlStep`, the same
  step for B runs at once (numpy over the batch axis);
- `closedloop.monitor`: `SafetyMonitor`, the run → hold → vent state machine, and
  `BatchSafetyMonitor`, B of them in arrays (both decide through `decide`);
- `closedloop.record`: `Recorder`, the one recorder, and `TIMESERIES_UNITS`, the one table of units.

Layers: imports `controllers` only; `hardware`, `softcbf_mj` and above import it.
"""
