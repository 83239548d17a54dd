"""Offscreen images of the MuJoCo scene: the OpenGL backend (chosen before MuJoCo is imported) and the camera's renders
and pinhole model. Imports the rooms below it (outputs, physics).
"""
