"""The controller under test (the bottom layer: numpy and QP solvers, never MuJoCo).

Public API (importable from `controllers` directly; each name is loaded from its module
on first use, so `import controllers.model.params` stays cheap):

- the plug-in contract (`controllers.contract.safety_filter`, docs/safety-filter.md): `SafetyFilter`, `Estimate`,
  `EstimateBatch`, `FilterOutput`, `BatchOutput`, `FilterContext`, `PassThroughFilter`, `OutputCheck`, `FilterReturnError`, `reset_filter`; what a plug-in
  declares it can do (`controllers.contract.capabilities`): `Capabilities`, `CapabilityError`, `filter_capabilities`,
  `nominal_capabilities`;
- the registry (`controllers.registry`): `FILTERS`, `NOMINALS`, `build_filter`,
  `build_nominal`, `parse_params`, `parameters`, `label`, `describe`;
- the paper's filter (`controllers.cbf.paper_filter`): `CBFFilter`, `CBFResult`, `paper_cbf`;
  its tunings (`controllers.cbf.barrier`): `Tuning`, `TUNINGS`, `get_tuning`;
- nominal controllers (`controllers.nominal`): `NominalController`, `SinusoidNominal`,
  `TipTracker`, `sinusoid`, `tip_tracker`;
- the models: `RobotParams`, `reference_robot` (`controllers.model.params`);
  `ForceSafeSet`, `Environment`, `LinearStiffness`, `PowerLawStiffness`,
  `paper_environment`, `paper_safe_set` (`controllers.model.safe_set`); `PCCDynamics`
  (`controllers.model.dynamics`); the kinematics module `controllers.model.pcc`;
- input errors (`controllers.core.errors`): `ControllerInputError`, `NonFiniteStateError`,
  `NonFiniteCommandError`.
"""

from __future__ import annotations

import importlib

_HOMES = {
    "controllers.contract.safety_filter": ("SafetyFilter", "Estimate", "EstimateBatch",
                                  "FilterOutput", "BatchOutput", "FilterContext", "PassThroughFilter", "OutputCheck",
                                  "FilterReturnError", "reset_filter"),
    "controllers.contract.capabilities": ("Capabilities", "CapabilityError", "filter_capabilities", "nominal_capabilities"),
    "controllers.registry": ("FILTERS", "NOMINALS", "build_filter", "build_nominal", "parse_params", "parameters",
                             "label", "describe"),
    "controllers.cbf.paper_filter": ("CBFFilter", "CBFResult", "paper_cbf"),
    "controllers.cbf.barrier": ("Tuning", "TUNINGS", "get_tuning"),
    "controllers.nominal": ("NominalController", "SinusoidNominal", "TipTracker", "sinusoid", "tip_tracker"),
    "controllers.model.params": ("RobotParams", "reference_robot"),
    "controllers.model.safe_set": ("ForceSafeSet", "Environment", "LinearStiffness", "PowerLawStiffness", "paper_environment",
                             "paper_safe_set"),
    "controllers.model.dynamics": ("PCCDynamics",),
    "controllers.core.errors": ("ControllerInputError", "NonFiniteStateError", "NonFiniteCommandError"),
}
_MODULE_OF = {name: module for module, names in _HOMES.items() for name in names}
__all__ = sorted(_MODULE_OF)


def __getattr__(name: str) -> object:
    """The public name `name`, imported from its module on first use (PEP 562)."""
    if name not in _MODULE_OF:
        raise AttributeError(f"module 'controllers' has no attribute {name!r}")
    value = getattr(importlib.import_module(_MODULE_OF[name]), name)
    globals()[name] = value
    return value
