"""The compare stage's artifact: the study's step and trajectory run with its starting and its tuned gains.

:class:`ResponsesRecord` is ``responses/responses.json``: one :class:`ResponseRun` per gain set,
controller (PID alone, FF + PID) and reference, with the run's CSV beside it; the published
step numbers beside the simulated ones where the study declares them (:class:`ReproductionRow`);
and, where the feedforward compensates creep, FF + PID with the same model refitted without creep
(:class:`CreepRow`). The compare stage writes it, the report reads it.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from piezopreload.core.artifacts import read_artifact, write_artifact
from piezopreload.core.errors import ArtifactError

__all__ = ["ResponseRun", "ReproductionRow", "CreepRow", "ResponsesRecord", "RESPONSE_FIGURES"]

KIND = "responses"
#: the figures of a run, None where they do not apply (a step that never settles)
RESPONSE_FIGURES = ("rise_s", "peak_s", "settling_s", "overshoot_N", "peak_command_V",
                    "tracking_rms_N", "tracking_max_N", "tracking_rms_after_change_N")


def _optional_number(doc: dict[str, Any], key: str, where: str) -> float | None:
    x = doc.get(key)
    if x is None:
        return None
    if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
        raise ArtifactError(f"{where}: field '{key}' must be a finite number or null, got {x!r}")
    return float(x)


def _text(doc: dict[str, Any], key: str, where: str) -> str:
    x = doc.get(key)
    if not isinstance(x, str):
        raise ArtifactError(f"{where}: field '{key}' must be text, got {x!r}")
    return x


@dataclass(frozen=True)
class ResponseRun:
    """One closed-loop run: which gains (``study``, ``tuned``), which controller (``pid``, ``ff+pid``), which
    reference (``step``, ``trajectory``), its CSV (relative to the output folder) and its figures."""

    gains: str
    controller: str
    reference: str
    csv: str
    rise_s: float | None = None
    peak_s: float | None = None
    settling_s: float | None = None
    overshoot_N: float | None = None
    peak_command_V: float | None = None
    tracking_rms_N: float | None = None
    tracking_max_N: float | None = None
    tracking_rms_after_change_N: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, doc: Any, where: str) -> ResponseRun:
        if not isinstance(doc, dict):
            raise ArtifactError(f"{where}: expected an object")
        gains, controller, reference, csv = (_text(doc, k, where) for k in ("gains", "controller", "reference", "csv"))
        return cls(gains, controller, reference, csv, **{k: _optional_number(doc, k, where) for k in RESPONSE_FIGURES})


@dataclass(frozen=True)
class ReproductionRow:
    """A published step number beside the study's gains' and the tuned gains' on the study's plant."""

    controller: str
    metric: str
    published: float
    study: float | None
    tuned: float | None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, doc: Any, where: str) -> ReproductionRow:
        if not isinstance(doc, dict):
            raise ArtifactError(f"{where}: expected an object")
        published = _optional_number(doc, "published", where)
        if published is None:
            raise ArtifactError(f"{where}: field 'published' is missing")
        return cls(_text(doc, "controller", where), _text(doc, "metric", where), published,
                   _optional_number(doc, "study", where), _optional_number(doc, "tuned", where))


@dataclass(frozen=True)
class CreepRow:
    """FF + PID with the feedforward's creep compensation (``creep``) or the same model refitted without it."""

    gains: str
    creep: bool
    feedforward: str
    reference: str
    settling_s: float | None = None
    overshoot_N: float | None = None
    tracking_rms_N: float | None = None
    tracking_rms_after_change_N: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, doc: Any, where: str) -> CreepRow:
        if not isinstance(doc, dict) or not isinstance(doc.get("creep"), bool):
            raise ArtifactError(f"{where}: expected an object with 'creep' true or false")
        numbers = [f.name for f in fields(cls)][4:]
        return cls(_text(doc, "gains", where), doc["creep"], _text(doc, "feedforward", where),
                   _text(doc, "reference", where), **{k: _optional_number(doc, k, where) for k in numbers})


def _rows(doc: dict[str, Any], key: str, kind: Any, where: str, optional: bool = False) -> tuple[Any, ...]:
    items = doc.get(key)
    if items is None and optional:
        return ()
    if not isinstance(items, list):
        raise ArtifactError(f"{where}: field '{key}' must be a list")
    return tuple(kind.from_dict(x, f"{where}: {key}[{i}]") for i, x in enumerate(items))


@dataclass(frozen=True)
class ResponsesRecord:
    """The compare stage's artifact (see the module docstring); ``signal`` and ``band_N`` say how the step times
    were read, ``seed`` the noise."""

    runs: tuple[ResponseRun, ...]
    band_N: float
    signal: str
    seed: int
    reproduction: tuple[ReproductionRow, ...] = ()
    creep_effect: tuple[CreepRow, ...] = ()
    inputs: dict[str, Any] = field(default_factory=dict)

    def run(self, gains: str, controller: str, reference: str) -> ResponseRun:
        """The run of ``gains`` with ``controller`` on ``reference``."""
        for r in self.runs:
            if (r.gains, r.controller, r.reference) == (gains, controller, reference):
                return r
        raise ArtifactError(f"the responses hold no run of {gains} {controller} on the {reference}")

    def to_dict(self) -> dict[str, Any]:
        return {"runs": [r.to_dict() for r in self.runs], "band_N": self.band_N, "signal": self.signal,
                "seed": self.seed, "reproduction": [r.to_dict() for r in self.reproduction] or None,
                "creep_effect": [r.to_dict() for r in self.creep_effect] or None, "inputs": dict(self.inputs)}

    @classmethod
    def from_dict(cls, doc: dict[str, Any], where: str = "the responses") -> ResponsesRecord:
        band, seed = doc.get("band_N"), doc.get("seed")
        if isinstance(band, bool) or not isinstance(band, int | float) or not band > 0:
            raise ArtifactError(f"{where}: field 'band_N' must be a number > 0, got {band!r}")
        if isinstance(seed, bool) or not isinstance(seed, int):
            raise ArtifactError(f"{where}: field 'seed' must be an integer, got {seed!r}")
        inputs = doc.get("inputs") or {}
        if not isinstance(inputs, dict):
            raise ArtifactError(f"{where}: field 'inputs' must be an object, got {inputs!r}")
        return cls(_rows(doc, "runs", ResponseRun, where), float(band), _text(doc, "signal", where), seed,
                   _rows(doc, "reproduction", ReproductionRow, where, True),
                   _rows(doc, "creep_effect", CreepRow, where, True), dict(inputs))

    def save(self, path: str | Path) -> Path:
        """Write ``responses.json`` atomically."""
        write_artifact(path, KIND, self.to_dict())
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> ResponsesRecord:
        """Read ``responses.json``: schema and every field checked."""
        return cls.from_dict(read_artifact(path, KIND), str(path))
