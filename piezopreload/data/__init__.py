"""Data shipped with piezopreload (see README.md in this folder)."""
