"""Control barrier function filters: the paper's CBF-QP (one state and B states, its compiled kernels and QP), the
standard CBF family and the backup CBF. Imports the rooms below it (core, model, energy, contract).
"""
