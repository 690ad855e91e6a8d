"""The physics and the maths of piezopreload: pure functions and frozen parameter objects.

No file I/O, no printing, no global state of their own; imports numpy, scipy and casadi, and the
ground floor (``core``): compiled code reaches the models through ``core.native``, which keeps
the build cache.
"""
