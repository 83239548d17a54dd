"""The whole hardware without hardware: the emulated valve board's plant hook, the virtual camera and the emulator that
joins them. Imports the rooms below it (outputs, physics, camera, loops).
"""
