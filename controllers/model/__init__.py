"""The arm's and the plate's model: PCC kinematics and dynamics (one implementation, any N, B states at once), the
robot's parameters, the force-safe set P and state prediction. Imports `controllers.core` only.
"""
