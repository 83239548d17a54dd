"""One vocabulary of settings for every way a run is configured (the command line, run
configuration files, studies, the hardware file): `vocabulary.settings` declares each
setting once (name, meaning, SI unit, valid range, plausibility bound) and checks values
against it (`check_value`); `vocabulary.files` reads a TOML or JSON settings file.

Standard library only, imported by `hardware` and `scenarios` alike (tests/test_layers.py).
"""
