"""Energies of the model: the escape energy Γ(u) (the least elastic energy that reaches outside P) and its bounds, and
the energy governor's compiled kernels (look-ups, certificate, bisections). Imports the rooms below it (core, model).
"""
