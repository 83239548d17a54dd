"""softcbf-mj: a MuJoCo testbed for force-safe control of soft robots with control barrier functions."""

__version__ = "0.1.0"
