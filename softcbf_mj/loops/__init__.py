"""The closed loops: plant → estimator → control step → plant, for one simulation, for B simulations and with the camera
in the loop, and the notice of numba's first compile. Imports the rooms below it (outputs, physics, camera).
"""
