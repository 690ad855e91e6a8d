"""The rig run's sidecar: what ran, with which limits and from where, what happened, how it ended.

A rig run writes its samples as CSV and this record beside it as JSON (kind ``rig-run``):
:class:`piezopreload.rig.runlog.RunLog` rewrites it atomically at the start, at every event and
at the end through :meth:`RigRunRecord.save` (the one writer), and every reader (the pipeline's
rig stage, the tests, a user's script) reads it through :meth:`RigRunRecord.load` (the one
reader) and attributes. The layout is the one the report has read since the first version
(``status``, ``backend``, ``rate_Hz``, ``realtime``, ``events``, ``summary`` ...), with the
interlocks' sources, the stall limit's derivation and the host check added.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Literal, overload

from piezopreload.artifacts.hostcheck import HostCheck
from piezopreload.core.artifacts import read_artifact, write_artifact
from piezopreload.core.errors import ArtifactError

__all__ = ["RigRunRecord", "RunOutcome", "RunTiming", "RunMetrics", "TripRecord", "StallLimit", "KIND", "STATUSES"]

KIND = "rig-run"
#: ``running`` until the run ends (a killed run stays so), ``not started`` when refused after its log was opened
STATUSES = ("running", "completed", "tripped", "not started")


class _Fields:
    """Reads the fields of one object of the document, naming the first that is missing or wrong."""

    def __init__(self, doc: Any, shown: str) -> None:
        if not isinstance(doc, dict):
            raise ArtifactError(f"{shown}: expected an object, got {type(doc).__name__}")
        self.doc, self.shown = doc, shown

    def _get(self, key: str, optional: bool) -> Any:
        if key not in self.doc or (optional and self.doc[key] is None):
            if optional:
                return None
            raise ArtifactError(f"{self.shown}: field '{key}' is missing")
        return self.doc[key]

    @overload
    def number(self, key: str, optional: Literal[False] = False) -> float: ...

    @overload
    def number(self, key: str, optional: Literal[True]) -> float | None: ...

    def number(self, key: str, optional: bool = False) -> float | None:
        x = self._get(key, optional)
        if x is None:
            return None
        if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
            raise ArtifactError(f"{self.shown}: field '{key}' must be a finite number, got {x!r}")
        return float(x)

    def count(self, key: str) -> int:
        x = self._get(key, False)
        if isinstance(x, bool) or not isinstance(x, int) or x < 0:
            raise ArtifactError(f"{self.shown}: field '{key}' must be a whole number >= 0, got {x!r}")
        return x

    @overload
    def text(self, key: str, optional: Literal[False] = False) -> str: ...

    @overload
    def text(self, key: str, optional: Literal[True]) -> str | None: ...

    def text(self, key: str, optional: bool = False) -> str | None:
        x = self._get(key, optional)
        if x is not None and not isinstance(x, str):
            raise ArtifactError(f"{self.shown}: field '{key}' must be text, got {x!r}")
        return x

    def flag(self, key: str) -> bool:
        x = self._get(key, False)
        if not isinstance(x, bool):
            raise ArtifactError(f"{self.shown}: field '{key}' must be true or false, got {x!r}")
        return x

    def mapping(self, key: str, optional: bool = False) -> dict[str, Any] | None:
        x = self._get(key, optional)
        if x is not None and not isinstance(x, dict):
            raise ArtifactError(f"{self.shown}: field '{key}' must be an object, got {type(x).__name__}")
        return x

    def items(self, key: str) -> list[Any]:
        x = self._get(key, False)
        if not isinstance(x, list):
            raise ArtifactError(f"{self.shown}: field '{key}' must be a list, got {type(x).__name__}")
        return x


@dataclass(frozen=True)
class TripRecord:
    """What stopped a run: the interlock's cause and words, the time on the run's timeline, the voltage held then."""

    cause: str
    detail: str
    t_s: float
    voltage_V: float

    @classmethod
    def from_dict(cls, doc: Any, shown: str) -> TripRecord:
        f = _Fields(doc, shown)
        return cls(f.text("cause"), f.text("detail"), f.number("t_s"), f.number("voltage_V"))


@dataclass(frozen=True)
class RunTiming:
    """How the loop kept time: deadlines missed, lateness, periods, stalls (updates held longer than two
    periods) and the longest hold, against the stall limit; ``sched_fifo``/``memory_locked`` say what the
    system granted (the native loop)."""

    loop: str
    realtime: bool
    rate_Hz: float
    cycles: int
    missed_deadlines: int
    lateness_p50_s: float
    lateness_p99_s: float
    lateness_max_s: float
    period_mean_s: float
    period_std_s: float
    period_max_s: float
    stalls: int
    stall_events_logged: int
    held_max_s: float
    stall_limit_s: float
    lost_samples: int
    sched_fifo: str | None = None
    memory_locked: str | None = None

    @classmethod
    def from_dict(cls, doc: Any, shown: str) -> RunTiming:
        f = _Fields(doc, shown)
        numbers: dict[str, Any] = {k: f.number(k)
                                   for k in ("rate_Hz", "lateness_p50_s", "lateness_p99_s", "lateness_max_s",
                                             "period_mean_s", "period_std_s", "period_max_s", "held_max_s",
                                             "stall_limit_s")}
        counts: dict[str, Any] = {k: f.count(k) for k in ("cycles", "missed_deadlines", "stalls", "stall_events_logged",
                                           "lost_samples")}
        return cls(loop=f.text("loop"), realtime=f.flag("realtime"), sched_fifo=f.text("sched_fifo", True),
                   memory_locked=f.text("memory_locked", True), **numbers, **counts)


_METRICS = ("peak_voltage_V", "rise_s", "peak_s", "settling_s", "overshoot_N", "tracking_rms_N", "tracking_max_N")


@dataclass(frozen=True)
class RunMetrics:
    """The step and tracking figures of a completed run's controlled samples (None where they do not apply:
    no step in the reference, or too short a run)."""

    samples: int
    peak_voltage_V: float | None = None
    rise_s: float | None = None
    peak_s: float | None = None
    settling_s: float | None = None
    overshoot_N: float | None = None
    tracking_rms_N: float | None = None
    tracking_max_N: float | None = None

    @classmethod
    def from_dict(cls, doc: Any, shown: str) -> RunMetrics:
        f = _Fields(doc, shown)
        return cls(f.count("samples"), **{k: f.number(k, True) for k in _METRICS})


@dataclass(frozen=True)
class RunOutcome:
    """How the run ended (the sidecar's ``summary``): ``trip`` for a tripped run and no ``metrics``; ``metrics``
    for a completed one."""

    cycles: int
    timing: RunTiming
    clamped_cycles: int
    trip: TripRecord | None = None
    metrics: RunMetrics | None = None
    controller_step: str = ""

    @classmethod
    def from_dict(cls, doc: Any, shown: str) -> RunOutcome:
        f = _Fields(doc, shown)
        trip, metrics = f.mapping("trip", True), f.mapping("metrics", True)
        out = cls(f.count("cycles"), RunTiming.from_dict(f.mapping("timing"), f"{shown}.timing"),
                  f.count("clamped_cycles"), None if trip is None else TripRecord.from_dict(trip, f"{shown}.trip"),
                  None if metrics is None else RunMetrics.from_dict(metrics, f"{shown}.metrics"),
                  f.text("controller_step") or "")
        if out.trip is not None and out.metrics is not None:
            raise ArtifactError(f"{shown}: a tripped run has no 'metrics'")
        return out


@dataclass(frozen=True)
class StallLimit:
    """The stall interlock's limit and how it was derived (:func:`piezopreload.rig.stall.derive_stall_limit`).

    ``plant_limit_s`` is the longest hold of the output the plant tolerates: from every state
    of the nominal run of ``reference``, the force with the command held (its amplifier, hysteresis
    and creep) stays ``sigmas`` sensor noise ``noise_N`` inside the force interlocks
    (``force_low_N``, ``force_max_N``) for that long; None where it stays inside over the whole
    ``horizon_s`` examined. ``worst_*`` is the hold that leaves the margin first (or, where
    none does, the one that comes nearest). ``limit_s`` is what the interlock uses and
    ``source`` where it came from; ``how`` says it in a sentence.
    """

    limit_s: float
    source: str
    how: str
    plant_limit_s: float | None
    horizon_s: float
    sigmas: float
    noise_N: float
    force_low_N: float
    force_max_N: float
    reference: str
    worst_t_s: float
    worst_force_N: float
    worst_held_V: float
    worst_margin_N: float
    drift_up_N: float
    drift_down_N: float

    @classmethod
    def from_dict(cls, doc: Any, shown: str) -> StallLimit:
        f = _Fields(doc, shown)
        numbers: dict[str, Any] = {x.name: f.number(x.name) for x in fields(cls)
                   if x.name not in ("source", "how", "reference", "plant_limit_s")}
        return cls(source=f.text("source"), how=f.text("how"), reference=f.text("reference"),
                   plant_limit_s=f.number("plant_limit_s", True), **numbers)


def _plain(x: Any) -> Any:
    """A record as the JSON it is written as (dataclasses to objects, tuples to lists)."""
    if hasattr(x, "to_dict"):
        return x.to_dict()
    if hasattr(x, "__dataclass_fields__"):
        return {k: _plain(v) for k, v in ((f.name, getattr(x, f.name)) for f in fields(x))}
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_plain(v) for v in x]
    return x


@dataclass(frozen=True)
class RigRunRecord:
    """A rig run's sidecar (see the module docstring).

    ``safety`` holds every limit the run used and ``safety_sources`` where each came from (the
    command line, the gain set's study, its plant, its gains, the executor's default);
    ``stall_limit`` how the stall limit was derived; ``host_check`` the check made before
    arming (real time) and ``host_accepted`` whether a failing host was run anyway
    (``--accept-host``); ``accepted_missed`` the requirements a gain set that is not validated
    missed and the user accepted by name (``--accept KEY``). ``summary`` is None until the run
    ends; ``reason`` says why a run was not started.
    """

    status: str = "running"
    created_utc: str = ""
    csv: str = ""
    columns: tuple[str, ...] = ()
    units: dict[str, str] = field(default_factory=dict)
    gain_set: str | None = None
    gain_set_sha256: str = ""
    feedforward_sha256: str = ""
    backend: str = ""
    rig_preset: str | None = None
    reference: str = ""
    reference_levels_N: tuple[float, ...] = ()
    rate_Hz: float = 1000.0
    realtime: bool = False
    seed: int = 0
    safety: dict[str, float] = field(default_factory=dict)
    safety_sources: dict[str, str] = field(default_factory=dict)
    stall_limit: StallLimit | None = None
    host_check: HostCheck | None = None
    host_accepted: bool = False
    accepted_missed: tuple[dict[str, Any], ...] = ()
    faults_injected: tuple[dict[str, Any], ...] = ()
    learned: dict[str, Any] | None = None
    endpoint: str | None = None
    users: tuple[str, ...] = ()
    served: bool = False
    events: tuple[dict[str, Any], ...] = ()
    summary: RunOutcome | None = None
    reason: str | None = None
    finished_utc: str | None = None

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ArtifactError(f"RigRunRecord.status must be one of {', '.join(STATUSES)}, got {self.status!r}")

    @property
    def trip(self) -> TripRecord | None:
        return None if self.summary is None else self.summary.trip

    def event(self, event: dict[str, Any]) -> RigRunRecord:
        """This record with ``event`` appended."""
        return replace(self, events=(*self.events, dict(event)))

    def to_dict(self) -> dict[str, Any]:
        out = {f.name: _plain(getattr(self, f.name)) for f in fields(self)}
        for key in ("stall_limit", "host_check", "learned", "endpoint", "reason", "finished_utc"):
            if out[key] is None:
                del out[key]
        if not self.served:
            for key in ("endpoint", "users", "served"):
                out.pop(key, None)
        return out

    @classmethod
    def from_dict(cls, doc: dict[str, Any], shown: str = "the run's sidecar") -> RigRunRecord:
        """The inverse of :meth:`to_dict`; an :class:`ArtifactError` names the field that is missing or wrong."""
        f = _Fields(doc, shown)
        status = f.text("status")
        if status not in STATUSES:
            raise ArtifactError(f"{shown}: field 'status' is {status!r}; expected one of {', '.join(STATUSES)}")
        summary, stall, host = f.mapping("summary", True), f.mapping("stall_limit", True), f.mapping("host_check", True)
        levels = f.items("reference_levels_N") if "reference_levels_N" in doc else []
        try:
            safety = {k: float(v) for k, v in (f.mapping("safety") or {}).items()}
        except (TypeError, ValueError) as exc:
            raise ArtifactError(f"{shown}: field 'safety' must hold numbers ({exc})") from None
        return cls(
            status=status, created_utc=f.text("created_utc") or "", csv=f.text("csv") or "",
            columns=tuple(f.items("columns")), units=dict(f.mapping("units") or {}), gain_set=f.text("gain_set", True),
            gain_set_sha256=f.text("gain_set_sha256") or "", feedforward_sha256=doc.get("feedforward_sha256") or "",
            backend=f.text("backend") or "", rig_preset=f.text("rig_preset", True), reference=f.text("reference") or "",
            reference_levels_N=tuple(float(x) for x in levels), rate_Hz=f.number("rate_Hz") or 0.0,
            realtime=f.flag("realtime"), seed=f.count("seed"), safety=safety,
            safety_sources={k: str(v) for k, v in (f.mapping("safety_sources", True) or {}).items()},
            stall_limit=None if stall is None else StallLimit.from_dict(stall, f"{shown}: stall_limit"),
            host_check=None if host is None else HostCheck.from_dict(host, f"{shown}: host_check"),
            host_accepted=bool(doc.get("host_accepted", False)), accepted_missed=tuple(
                f.items("accepted_missed") if "accepted_missed" in doc else ()),
            faults_injected=tuple(f.items("faults_injected")), learned=f.mapping("learned", True),
            endpoint=f.text("endpoint", True), users=tuple(doc.get("users") or ()),
            served=bool(doc.get("served", False)), events=tuple(f.items("events")),
            summary=None if summary is None else RunOutcome.from_dict(summary, f"{shown}: summary"),
            reason=f.text("reason", True), finished_utc=f.text("finished_utc", True))

    # ---- the artifact: one reader, one writer ---------------------------------------------------
    @classmethod
    def load(cls, path: str | Path) -> RigRunRecord:
        """Read a run's sidecar: schema and fields checked."""
        return cls.from_dict(read_artifact(path, KIND), str(path))

    def save(self, path: str | Path) -> RigRunRecord:
        """Write the sidecar atomically (a reader sees the previous one or this one, never a part)."""
        write_artifact(path, KIND, self.to_dict())
        return self


