"""Gains side by side on a study's rig: the tuning's comparison table and the closed-loop responses.

:func:`compare_gains` scores each candidate (the study's, SIMC's, the tuned gains) without and
with the feedforward on the nominal rig, as the validation scores a plant
(:func:`~piezopreload.tuning.validate.evaluate`); :func:`responses` simulates the study's step
and trajectory for its starting and its tuned gains, PID alone and with the feedforward, and
:func:`reproduction` lays the step numbers a study declares published (``[published]``) beside them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from piezopreload.artifacts.responses import CreepRow, ReproductionRow
from piezopreload.artifacts.tuning import ComparisonRow
from piezopreload.artifacts.validation import Criteria
from piezopreload.core.artifacts import finite_or_none
from piezopreload.core.progress import Bar
from piezopreload.models.actuator import Plant, Rig
from piezopreload.models.closedloop import ClosedLoopRun, Reference, simulate
from piezopreload.models.controller import Controller, PIDGains
from piezopreload.models.hysteresis import inverse_at
from piezopreload.models.metrics import Signal, run_numbers
from piezopreload.tuning.calibrate import CONTROLLERS, Reproduction
from piezopreload.tuning.feedforward import FeedforwardModel
from piezopreload.tuning.validate import evaluate

__all__ = ["compare_gains", "tracking_improvement", "Response", "responses", "creep_effect", "reproduction",
           "published_rows", "PublishedRow"]


def compare_gains(rig: Plant, step: Reference, trajectory: Reference, candidates: dict[str, PIDGains],
                  feedforward: FeedforwardModel, criteria: Criteria, seed: int) -> tuple[ComparisonRow, ...]:
    """Each gain set without and with the feedforward on the nominal rig: one row each."""
    rows = []
    for name, gains in candidates.items():
        for ff in (False, True):
            m = evaluate(gains, feedforward if ff else None, rig, step, trajectory, criteria, seed)
            rows.append(ComparisonRow(
                gains=name, feedforward=ff,
                rise_s=finite_or_none(m["rise_s"][0]), settling_s=finite_or_none(m["settling_s"][0]),
                settling_measured_s=finite_or_none(m["settling_measured_s"][0]),
                overshoot_N=float(m["overshoot_N"][0]), tracking_rms_N=float(m["tracking_rms_all_N"][0]),
                tracking_rms_after_change_N=float(m["tracking_rms_N"][0]),
                peak_command_V=float(m["peak_voltage_V"][0]),
            ))
    return tuple(rows)


def tracking_improvement(table: Sequence[ComparisonRow]) -> dict[str, float | None]:
    """The study's starting gains' tracking RMS over the tuned one (with feedforward), both ways of scoring it (None
    where the tuned loop's is 0 or not a number: a reference with nothing to score after its changes)."""
    row = {(r.gains, r.feedforward): r for r in table}
    tuned = row[("tuned", True)]

    def ratio(num: Any, den: Any) -> float | None:
        return float(num) / float(den) if num is not None and den is not None and float(den) > 0.0 else None

    out = {}
    for ff in (False, True):
        key = "study_ff_pid" if ff else "study_pid"
        out[f"{key}_over_tuned"] = ratio(row[("study", ff)].tracking_rms_N, tuned.tracking_rms_N)
        out[f"{key}_over_tuned_after_change"] = ratio(row[("study", ff)].tracking_rms_after_change_N,
                                                      tuned.tracking_rms_after_change_N)
    return out


@dataclass(frozen=True, eq=False)
class Response:
    """One closed-loop run of :func:`responses` and its numbers (:func:`~piezopreload.models.metrics.run_numbers`)."""

    gains: str
    controller: str
    reference: str
    run: ClosedLoopRun
    numbers: dict[str, float | None]

    @property
    def label(self) -> str:
        return f"{self.gains}-{self.controller.replace('+', '-')}-{self.reference}"


def responses(rig: Plant, references: dict[str, Reference], candidates: dict[str, PIDGains],
              feedforward: FeedforwardModel, *, seed: int, band_N: float, signal: Signal, after_change_s: float,
              bar: Bar | None = None,
              controllers: tuple[str, ...] = CONTROLLERS) -> list[Response]:
    """Every candidate, PID alone and with the feedforward (``controllers``), over every reference (noise ``seed``)."""
    plant = Rig(rig)
    out: list[Response] = []
    total = len(candidates) * len(controllers) * len(references)
    for name, gains in candidates.items():
        for controller in controllers:
            ff = inverse_at(feedforward, plant.dt_s) if controller == "ff+pid" else None
            for ref_name, ref in references.items():
                run = simulate(plant, Controller(gains, plant.dt_s, ff), ref, seed=seed)
                out.append(Response(name, controller, ref_name, run, run_numbers(run, band_N, signal, after_change_s)))
                if bar is not None:
                    bar(len(out), total)
    return out


def creep_effect(rig: Plant, references: dict[str, Reference], candidates: dict[str, PIDGains],
                 with_creep: FeedforwardModel, without_creep: FeedforwardModel, *, seed: int, band_N: float,
                 signal: Signal, after_change_s: float) -> list[CreepRow]:
    """FF + PID with the feedforward's creep compensation and with the same model refitted without creep.

    One row per gains, feedforward and reference, on one noise draw (``seed``, the same for both):
    the step numbers (rise, peak, settling, overshoot) and the tracking errors.
    """
    rows = []
    for creep, model in ((False, without_creep), (True, with_creep)):
        for r in responses(rig, references, candidates, model, seed=seed, band_N=band_N, signal=signal,
                           after_change_s=after_change_s, controllers=("ff+pid",)):
            n = r.numbers
            rows.append(CreepRow(r.gains, creep, model.kind, r.reference, n.get("settling_s"), n.get("overshoot_N"),
                                 n.get("tracking_rms_N"), n.get("tracking_rms_after_change_N")))
    return rows


def reproduction(runs: list[Response], published: dict[str, dict[str, float]],
                 reference: str = "step") -> list[ReproductionRow]:
    """Published step numbers (by controller and metric: a study's ``[published]``) beside the study's and the tuned
    gains' on its plant, per controller and metric."""
    rows = []
    for controller in CONTROLLERS:
        for metric in ("rise_s", "peak_s", "settling_s"):
            got = {r.gains: r.numbers[metric] for r in runs if r.controller == controller and r.reference == reference}
            rows.append(ReproductionRow(controller, metric, published[controller][metric], got["study"],
                                        got["tuned"]))
    return rows


@dataclass(frozen=True)
class PublishedRow:
    """One published step number beside the simulation's: their ratio, whether it lies within 25 % of the published
    one, and the simulated number's range over the noise realisations (a time never reached is None, not within).

    Parameters
    ----------
    controller : str
        ``pid`` or ``ff+pid``.
    metric : str
        ``rise_s``, ``peak_s`` or ``settling_s``.
    paper : float
        The published number (s).
    simulated : float or None
        The simulated one (s; None: never reached).
    ratio : float or None
        Simulated over published.
    within_25pct : bool
        Whether the ratio lies within 0.75 to 1.25.
    range : (float or None, float or None)
        The least and the largest simulated number over the noise realisations (s).
    """

    controller: str
    metric: str
    paper: float
    simulated: float | None
    ratio: float | None
    within_25pct: bool
    range: tuple[float | None, float | None]

    def to_dict(self) -> dict[str, Any]:
        """The row as ``reproduce --json`` prints it.

        Returns
        -------
        dict
            ``controller``, ``metric``, ``paper`` and ``simulated`` (s), ``ratio``, ``within_25pct`` and ``range`` (s).
        """
        return {"controller": self.controller, "metric": self.metric, "paper": self.paper,
                "simulated": self.simulated, "ratio": self.ratio, "within_25pct": self.within_25pct,
                "range": list(self.range)}


def published_rows(rep: Reproduction, published: dict[str, dict[str, float]]) -> tuple[PublishedRow, ...]:
    """The paper's six step numbers beside a :class:`Reproduction`'s, each judged within 25 % of the paper's,
    with its range over the noise realisations (a time never reached is None and not within).

    Parameters
    ----------
    rep : Reproduction
        The simulated step numbers, both controllers, with their range over the noise realisations.
    published : dict of str to dict of str to float
        The published numbers by controller (``pid``, ``ff+pid``) and metric (``rise_s``, ``peak_s``,
        ``settling_s``), in s.

    Returns
    -------
    tuple of PublishedRow
        One row per controller and metric.
    """
    rows = []
    for r in rep.table(published):
        low, high = rep.spread[r["controller"]][r["metric"]]
        reached = r["simulated"] == r["simulated"]  # nan: never reached
        rows.append(PublishedRow(r["controller"], r["metric"], r["paper"], r["simulated"] if reached else None,
                                 r["ratio"] if reached else None, reached and bool(abs(r["ratio"] - 1.0) <= 0.25),
                                 (finite_or_none(low), finite_or_none(high))))
    return tuple(rows)
