"""The plants: the plant interface, the MuJoCo ground truth (its MJCF model, the flexure plate, table friction, the one
builder `build_truth`), the PCC simulation plant, their batched forms and the model's calibration from motion data.
Imports `softcbf_mj.outputs` at most.
"""
