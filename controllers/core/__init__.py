"""The controller's base: number bounds and their check, input errors, interrupts and deferred imports (standard library
and numpy only; imports nothing else of `controllers`).
"""
