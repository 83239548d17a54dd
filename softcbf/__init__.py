"""The application layer of softcbf-mj: the `softcbf` command line, the hardware mode's
command line and robustness studies.

It sits on top of `scenarios` (which sits on the testbed `softcbf_mj` and on
`controllers`, `perception` and `hardware`); nothing below imports it.
"""
