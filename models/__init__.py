"""The physics and the maths of piezopreload: pure functions and frozen parameter objects.

No file I/O, no printing, no global state; imports numpy, scipy and casadi only.
"""
