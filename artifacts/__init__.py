"""The artifacts: one typed record per kind of document the tool writes, with its one reader and one writer.

This floor sits above :mod:`piezopreload.models` (whose types the records hold) and below the
floors that compute them (design, tuning, rig) and the one that reports them (reports), so a
record is written by the floor that computes it and read, typed, by every floor above: the
report never reads a raw dict. Each record is a frozen dataclass with ``to_dict()``,
``from_dict()`` (every field checked, a missing or non-finite one named), ``save(path)``
(atomic, through :func:`piezopreload.core.artifacts.write_artifact`) and ``load(path)``.
"""
