"""One vocabulary of settings for every way a run is configured (the command line, run
configuration files, studies, the environment, the hardware file): `vocabulary.settings` declares
each setting once (name, meaning, SI unit, valid range, plausibility bound, default) and checks
values against it (`check_value`); `vocabulary.sections` makes frozen, checked sections of them;
`vocabulary.run_sections` holds the typed sections every surface composes (the run, the controller's
model, the ground truth's true arm and plate, the camera path); `vocabulary.files` reads a TOML or
JSON settings file.

The standard library and the controllers' bottom declarations only (`controllers.core.bounds`,
`controllers.contract.filter_parameters`, the paper's numbers of `controllers.model.paper_experiment`), imported by
`hardware`, `softcbf_mj` and `scenarios` alike (tests/test_layers.py).
"""
