"""The reference generators of the tests' stored results (tests/data/*_references.npz): each is the module its test
imports (the cases, columns and tolerances) and a command that regenerates or compares its file (its docstring)."""
