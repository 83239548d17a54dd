"""Reference governors: the energy governors (e-erg, c-erg) and their online estimates (actuator gain, plate, camera
error), and the quasi-static governor. Imports the rooms below it (core, model, energy, contract, cbf).
"""
