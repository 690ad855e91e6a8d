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
from dataclasses import fields, replace
from pathlib import Path
from typing import Any, ClassVar

from piezopreload.artifacts.hostcheck import HostCheck
from piezopreload.core.errors import ArtifactError
from piezopreload.core.records import Artifact, Raw, Record, entry, record
from piezopreload.models.controller import OUTPUT_MAX_V, OUTPUT_MIN_V

__all__ = ["Safety", "SafetySources", "RigRunRecord", "RunOutcome", "RunTiming", "RunMetrics", "TripRecord",
           "StallLimit", "KIND", "STATUSES"]

KIND = "rig-run"
#: ``running`` until the run ends (a killed run stays so), ``not started`` when refused after its log was opened
STATUSES = ("running", "completed", "tripped", "not started")


@record
class TripRecord(Record):
    """What stopped a run."""

    cause: str = entry("The interlock's cause (``force_high``, ``stall``, ...).")
    detail: str = entry("The interlock's words, with its numbers.")
    t_s: float = entry("The time on the run's timeline.", unit="s")
    voltage_V: float = entry("The voltage held then.", unit="V")


@record
class RunTiming(Record):
    """How the loop kept time: deadlines missed, lateness, periods, stalls (updates held longer than two
    periods) and the longest hold, against the stall limit; ``sched_fifo``/``memory_locked`` say what the
    system granted (the native loop)."""

    loop: str = entry("Which loop ran (the native loop in C, the Python loop).")
    realtime: bool = entry("Whether it ran on the wall clock.")
    rate_Hz: float = entry("Its rate.", unit="Hz")
    cycles: int = entry("The cycles it ran.", ge=0)
    missed_deadlines: int = entry("The cycles that missed their deadline.", ge=0)
    lateness_p50_s: float = entry("The median lateness of a cycle.", unit="s")
    lateness_p99_s: float = entry("Its 99th percentile.", unit="s")
    lateness_max_s: float = entry("The latest cycle's lateness.", unit="s")
    period_mean_s: float = entry("The mean period.", unit="s")
    period_std_s: float = entry("The periods' standard deviation.", unit="s")
    period_max_s: float = entry("The longest period.", unit="s")
    stalls: int = entry("The updates held longer than two periods.", ge=0)
    stall_events_logged: int = entry("The stalls logged as events.", ge=0)
    held_max_s: float = entry("The longest hold of the output.", unit="s")
    stall_limit_s: float = entry("The stall interlock's limit.", unit="s")
    lost_samples: int = entry("The samples the log lost.", ge=0)
    sched_fifo: str | None = entry("Whether the loop's thread got SCHED_FIFO.", default=None)
    memory_locked: str | None = entry("Whether its memory was locked.", default=None)


_METRICS = ("peak_voltage_V", "rise_s", "peak_s", "settling_s", "overshoot_N", "tracking_rms_N", "tracking_max_N")


@record
class RunMetrics(Record):
    """The step and tracking figures of a completed run's controlled samples (None where they do not apply:
    no step in the reference, or too short a run)."""

    samples: int = entry("The controlled samples.", ge=0)
    peak_voltage_V: float | None = entry("The highest voltage.", unit="V", default=None)
    rise_s: float | None = entry("The step's rise time.", unit="s", default=None)
    peak_s: float | None = entry("The step's peak time.", unit="s", default=None)
    settling_s: float | None = entry("The step's settling time.", unit="s", default=None)
    overshoot_N: float | None = entry("The step's overshoot.", unit="N", default=None)
    tracking_rms_N: float | None = entry("The RMS tracking error.", unit="N", default=None)
    tracking_max_N: float | None = entry("The largest tracking error.", unit="N", default=None)


@record
class RunOutcome(Record):
    """How the run ended (the sidecar's ``summary``): ``trip`` for a tripped run and no ``metrics``; ``metrics``
    for a completed one."""

    cycles: int = entry("The cycles it ran.", ge=0)
    timing: RunTiming = entry("How the loop kept time.")
    clamped_cycles: int = entry("The cycles whose command was clamped to the output range.", ge=0)
    trip: TripRecord | None = entry("What stopped a tripped run.", default=None)
    metrics: RunMetrics | None = entry("A completed run's figures.", default=None)
    controller_step: str = entry("The controller step that ran (its source).", default="", required=True)

    def _check_document(self, raw: Raw) -> None:
        if self.trip is not None and self.metrics is not None:
            raise raw.fail("metrics", "must be null: a tripped run has no 'metrics'")


@record
class StallLimit(Record):
    """The stall interlock's limit and how it was derived (:func:`piezopreload.rig.stall.derive_stall_limit`).

    ``plant_limit_s`` is the longest hold of the output the plant tolerates: from every state
    of the nominal run of ``reference``, the force with the command held (its amplifier, hysteresis
    and creep) stays ``sigmas`` sensor noise ``noise_N`` inside the force interlocks
    (``force_low_N``, ``force_max_N``) for that long; None where it stays inside over the whole
    ``horizon_s`` examined. ``worst_*`` is the hold that leaves the margin first (or, where
    none does, the one that comes nearest). ``limit_s`` is what the interlock uses and
    ``source`` where it came from; ``how`` says it in a sentence.
    """

    limit_s: float = entry("The limit the interlock uses.", unit="s")
    source: str = entry("Where it came from.")
    how: str = entry("How it was derived, in a sentence.")
    plant_limit_s: float | None = entry("The longest hold the plant tolerates (None: longer than ``horizon_s``).",
                                        unit="s", absent=None)
    horizon_s: float = entry("The holds examined.", unit="s")
    sigmas: float = entry("The margin inside the interlocks, in sensor noise.")
    noise_N: float = entry("The sensor noise.", unit="N")
    force_low_N: float = entry("The low force interlock.", unit="N")
    force_max_N: float = entry("The high force interlock.", unit="N")
    reference: str = entry("The reference whose nominal run was examined.")
    worst_t_s: float = entry("When the worst hold starts.", unit="s")
    worst_force_N: float = entry("The force there.", unit="N")
    worst_held_V: float = entry("The command held.", unit="V")
    worst_margin_N: float = entry("Its least margin to an interlock.", unit="N")
    drift_up_N: float = entry("The largest drift up under a hold.", unit="N")
    drift_down_N: float = entry("The largest drift down under a hold.", unit="N")


@record
class Safety(Record):
    """The interlocks' limits and the command's shaping; the defaults suit the paper's rig.

    A session (:func:`piezopreload.rig.session.interlocks`) builds it from the gain set: its study's ``[rig_run]``
    limits, its plant (bolt preload, the A/D's range, the stall limit) and its gains (the command range), and records
    where each value came from. A run's sidecar holds it (``safety``, every limit the run used): a document must
    give every limit, none is taken from these defaults.
    """

    v_min_V: float = entry("The command's low end.", unit="V", default=OUTPUT_MIN_V, required=True)
    v_max_V: float = entry("The command's high end.", unit="V", default=OUTPUT_MAX_V, required=True)
    slew_V_per_s: float = entry("The command's largest slew.", unit="V/s", default=20_000.0, required=True)
    force_max_N: float = entry("The highest force.", unit="N", default=150.0, required=True)
    bolt_preload_N: float = entry("The bolts' preload (the force's floor lies a margin below it).", unit="N",
                                  default=25.0, required=True)
    force_low_margin_N: float = entry("The margin below the bolts' preload the force may fall to.", unit="N",
                                      default=10.0, required=True)
    sensor_min_N: float = entry("The sensor's lowest reading.", unit="N", default=-1000.0, required=True)
    sensor_max_N: float = entry("The sensor's highest reading.", unit="N", default=1000.0, required=True)
    stale_after_s: float = entry("How old a reading may be.", unit="s", default=0.01, required=True)
    stall_limit_s: float = entry("The longest the output may be held without an update (a stall longer than this "
                                 "trips).", unit="s", default=0.05, required=True)
    ramp_s: float = entry("The ramp down's length.", unit="s", default=0.5, required=True)
    safe_V: float = entry("The command the ramp ends on.", unit="V", default=0.0, required=True)

    def __post_init__(self) -> None:
        for name in (f.name for f in fields(self)):
            value = getattr(self, name)
            if isinstance(value, bool) or not (isinstance(value, int | float) and math.isfinite(value)):
                raise ValueError(f"safety.{name} must be a finite number, got {value!r}")
        if not self.v_min_V < self.v_max_V:
            raise ValueError(f"safety needs v_min_V < v_max_V, got {self.v_min_V} and {self.v_max_V}")
        if not self.v_min_V <= self.safe_V <= self.v_max_V:
            raise ValueError(f"safety.safe_V must lie in {self.v_min_V}..{self.v_max_V} V, got {self.safe_V}")
        for name in ("slew_V_per_s", "stale_after_s", "ramp_s", "force_low_margin_N", "stall_limit_s"):
            if getattr(self, name) <= 0:
                raise ValueError(f"safety.{name} must be > 0, got {getattr(self, name)}")
        low_N = self.bolt_preload_N - self.force_low_margin_N
        if not self.sensor_min_N < low_N < self.force_max_N <= self.sensor_max_N:
            raise ValueError(f"safety needs sensor_min_N < bolt_preload_N - force_low_margin_N < force_max_N <= "
                             f"sensor_max_N, got {self.sensor_min_N:g} < {self.force_low_N:g} "
                             f"< {self.force_max_N:g} <= {self.sensor_max_N:g}")

    @property
    def force_low_N(self) -> float:
        """The force below which ``force_low`` trips: the bolt preload less the margin."""
        return self.bolt_preload_N - self.force_low_margin_N


@record
class SafetySources(Record):
    """Where each of a run's limits came from, in words (the command line, the gain set's study, its plant, its gains
    or the executor's default): one field for each field of :class:`Safety`, under the same name. The session that
    works out the limits (:func:`piezopreload.rig.limits.run_limits`) sets every one; a sidecar's ``safety_sources``
    must give every one. The fields stand in the order the session works the limits out in (the executor's, the
    plant's and the gains', then the study's), the order sidecars have always written them in.
    """

    slew_V_per_s: str = entry("Where the command's largest slew came from.")
    stale_after_s: str = entry("Where the oldest a reading may be came from.")
    v_min_V: str = entry("Where the command's low end came from.")
    v_max_V: str = entry("Where the command's high end came from.")
    safe_V: str = entry("Where the command the ramp ends on came from.")
    bolt_preload_N: str = entry("Where the bolts' preload came from.")
    sensor_min_N: str = entry("Where the sensor's lowest reading came from.")
    sensor_max_N: str = entry("Where the sensor's highest reading came from.")
    force_max_N: str = entry("Where the highest force came from.")
    force_low_margin_N: str = entry("Where the margin below the bolts' preload came from.")
    ramp_s: str = entry("Where the ramp down's length came from.")
    stall_limit_s: str = entry("Where the stall limit came from.")


@record
class RigRunRecord(Artifact):
    """A rig run's sidecar (see the module docstring).

    ``safety`` holds every limit the run used and ``safety_sources`` where each came from (the
    command line, the gain set's study, its plant, its gains, the executor's default);
    ``stall_limit`` how the stall limit was derived; ``host_check`` the check made before
    arming (real time) and ``host_accepted`` whether a failing host was run anyway
    (``--accept-host``); ``accepted_missed`` the requirements a gain set that is not validated
    missed and the user accepted by name (``--accept KEY``). ``summary`` is None until the run
    ends; ``reason`` says why a run was not started.
    """

    KIND: ClassVar[str] = KIND
    NOUN: ClassVar[str] = "the run's sidecar"
    AGAIN: ClassVar[str] = "run the rig again ('piezopreload rig run')"

    status: str = entry("``running`` until the run ends (a killed run stays so), then ``completed`` or ``tripped``; "
                        "``not started`` when refused after its log was opened.", choices=STATUSES,
                        default="running", required=True)
    created_utc: str = entry("When the run started (UTC, ISO 8601).", default="", required=True)
    csv: str = entry("Its samples' CSV (beside the sidecar).", default="", required=True)
    columns: tuple[str, ...] = entry("The CSV's columns.", default=(), required=True)
    units: dict[str, str] = entry("Each column's unit.", default={}, required=True)
    gain_set: str | None = entry("The gain set's file.", default=None)
    gain_set_sha256: str = entry("The gain set's content hash.", default="", required=True)
    feedforward_sha256: str = entry("The feedforward's hash.", default="")
    backend: str = entry("The backend that ran (``sim``, a plug-in's).", default="", required=True)
    rig_preset: str | None = entry("The plant's name.", default=None)
    reference: str = entry("The reference run (a name, or a CSV).", default="", required=True)
    reference_levels_N: tuple[float, ...] = entry("The reference's levels.", unit="N", default=())
    rate_Hz: float = entry("The loop's rate.", unit="Hz", default=1000.0, required=True)
    realtime: bool = entry("Whether it ran on the wall clock.", default=False, required=True)
    seed: int = entry("The simulated backend's noise seed.", ge=0, default=0, required=True)
    safety: Safety = entry("Every limit the run used.", default=Safety(), required=True)
    safety_sources: SafetySources | None = entry("Where each limit came from (None: a sidecar that does not say).",
                                                 default=None, omit=True)
    stall_limit: StallLimit | None = entry("How the stall limit was derived.", default=None, omit=True)
    host_check: HostCheck | None = entry("The host check made before arming.", default=None, omit=True)
    host_accepted: bool = entry("Whether a failing host was run anyway (``--accept-host``).", default=False)
    accepted_missed: tuple[dict[str, Any], ...] = entry("The requirements the gain set missed and the user accepted "
                                                        "by name.", default=())
    faults_injected: tuple[dict[str, Any], ...] = entry("The faults injected into the run.", default=(),
                                                        required=True)
    learned: dict[str, Any] | None = entry("The learned signal played, where one was.", default=None, omit=True)
    endpoint: str | None = entry("The OPC UA endpoint a served rig listened on.", default=None, omit=True)
    users: tuple[str, ...] = entry("The served rig's users.", default=())
    served: bool = entry("Whether the rig was served over OPC UA.", default=False)
    events: tuple[dict[str, Any], ...] = entry("What happened, in order.", default=(), required=True)
    summary: RunOutcome | None = entry("How the run ended (None until it ends).", default=None, required=True)
    reason: str | None = entry("Why a run was not started.", default=None, omit=True)
    finished_utc: str | None = entry("When the run ended (UTC).", default=None, omit=True)

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
        """The sidecar's body; a rig that was not served leaves its endpoint and users out.

        Returns
        -------
        dict
            The document's body.
        """
        out = super().to_dict()
        if not self.served:
            for key in ("endpoint", "users", "served"):
                out.pop(key, None)
        return out

    # ---- the artifact: one reader, one writer ---------------------------------------------------
    def save(self, path: str | Path) -> RigRunRecord:
        """Write the sidecar atomically (a reader sees the previous one or this one, never a part).

        Parameters
        ----------
        path : str or Path
            The file.

        Returns
        -------
        RigRunRecord
            This record.
        """
        self._write(path)
        return self
