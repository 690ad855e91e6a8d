"""The artifacts: one typed record per kind of document the tool writes, with its one reader and one writer.

This floor sits above :mod:`piezopreload.models` (whose types the records hold) and below the
floors that compute them (design, tuning, rig) and the one that reports them (reports), so a
record is written by the floor that computes it and read, typed, by every floor above: the
report never reads a raw dict. Each record is a frozen dataclass whose fields are declared once
(:func:`piezopreload.core.records.entry`); its ``from_dict()`` (every field checked, a missing,
wrong or non-finite one named in one message format), ``to_dict()``, the fields its kind requires
(:data:`piezopreload.artifacts.registry.KINDS`, the one list of the kinds) and its docstring's
``Parameters`` come from that declaration; an artifact's ``save(path)`` writes it atomically and
``load(path)`` is its one reader.

Importing this package imports every record's module (nothing is registered by it: a record's reader
and writer take its own declaration of its kind).
"""

from piezopreload.artifacts import (  # noqa: F401 (the records' modules, as attributes of the package)
    design,
    gainset,
    hostcheck,
    hysteresis,
    learned,
    learning,
    plant,
    requirements,
    responses,
    rigrun,
    schedule,
    sweep,
    system,
    thermal,
    tuning,
    validation,
)
