"""The rig executor, backends, interlocks and gain export (not implemented yet: see the open rig issue)."""
