"""Every kind of artifact the tool writes, listed once: :data:`KINDS`.

Each record of :mod:`piezopreload.artifacts` declares its own kind (:func:`~piezopreload.core.records.kind_of`
the record: its name, the fields its documents must hold, its hash, what writes it again), and its one
reader and writer take that declaration; the three documents no record declares yet are
:data:`piezopreload.core.artifacts.DOCUMENTS`. :data:`KINDS` is made here, from this list, when this module is
read: nothing is added to it as modules are imported, and a kind named twice is refused here.
:func:`read_artifact` and :func:`write_artifact` take a kind by its name and look it up in this list.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from piezopreload.artifacts.design import DesignRecord
from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.hysteresis import IdentifiedModel
from piezopreload.artifacts.learned import LearnedSignal
from piezopreload.artifacts.learning import LearningRecord
from piezopreload.artifacts.plant import DesignedPlant
from piezopreload.artifacts.responses import ResponsesRecord
from piezopreload.artifacts.rigrun import RigRunRecord
from piezopreload.artifacts.sweep import SweepRecord
from piezopreload.artifacts.system import SystemRecord
from piezopreload.artifacts.tuning import TuningResult
from piezopreload.artifacts.validation import ValidationResult
from piezopreload.core import artifacts as envelope
from piezopreload.core.artifacts import DOCUMENTS, Kinds
from piezopreload.core.records import Artifact, kind_of
from piezopreload.core.stagecache import CacheEntry

__all__ = ["ARTIFACTS", "KINDS", "read_artifact", "write_artifact"]

#: the records that are whole artifacts, one per kind (the stage store's entry is the core's own)
ARTIFACTS: tuple[type[Artifact], ...] = (
    IdentifiedModel, DesignRecord, DesignedPlant, TuningResult, ValidationResult, GainSet, ResponsesRecord,
    LearningRecord, LearnedSignal, SystemRecord, RigRunRecord, SweepRecord, CacheEntry,
)

#: each artifact kind by name, to the fields its documents must hold (``KINDS.kind(name)``: its declaration)
KINDS = Kinds([*(kind_of(cls) for cls in ARTIFACTS), *DOCUMENTS])


def read_artifact(path: str | Path, kind: str, *, fields: bool = True) -> dict[str, Any]:
    """:func:`piezopreload.core.artifacts.read_artifact` with the kind named (a key of :data:`KINDS`).

    Parameters
    ----------
    path : str or Path
        The file.
    kind : str
        The kind's name (``gain-set``).
    fields : bool
        Whether to check the kind's required fields.

    Returns
    -------
    dict
        The document, checked.
    """
    return envelope.read_artifact(path, KINDS.kind(kind), fields=fields)


def write_artifact(path: str | Path, kind: str, body: dict[str, Any]) -> dict[str, Any]:
    """:func:`piezopreload.core.artifacts.write_artifact` with the kind named (a key of :data:`KINDS`).

    Parameters
    ----------
    path : str or Path
        The file.
    kind : str
        The kind's name.
    body : dict
        The document's fields.

    Returns
    -------
    dict
        The whole document written.
    """
    return envelope.write_artifact(path, KINDS.kind(kind), body)
