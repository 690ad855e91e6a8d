"""What a study's steps return: :class:`TuningResult` (``study.tune()``) and :class:`StudyRun` (``study.simulate()``).

Each result carries its numbers, ``to_dict()`` (what ``--json`` prints or the artifact
holds) and ``plot()`` (a matplotlib Figure, no pyplot state). The domain computations are the
floors': the tuning (:mod:`piezopreload.tuning.pid`), the comparison
(:mod:`piezopreload.tuning.compare`), the verdict (:mod:`piezopreload.tuning.verdict`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from piezopreload.artifacts.gainset import REFERENCES, GainSet, gains_from_dict, gains_to_dict
from piezopreload.core.artifacts import read_artifact, write_artifact
from piezopreload.core.errors import InfeasibleError, InputError
from piezopreload.core.parallel import beside
from piezopreload.models.actuator import Rig
from piezopreload.models.closedloop import ClosedLoopRun
from piezopreload.models.closedloop import simulate as simulate_loop
from piezopreload.models.controller import Controller, PIDGains
from piezopreload.models.metrics import StepMetrics, run_numbers
from piezopreload.study import Study
from piezopreload.tuning.calibrate import CONTROLLERS, PAPER_RESULTS
from piezopreload.tuning.calibrate import reproduce as reproduce_paper
from piezopreload.tuning.compare import compare_gains, reproduction_summary, tracking_improvement
from piezopreload.tuning.feedforward import IdentifiedFeedforward
from piezopreload.tuning.pid import TuningInfeasible, minimum_time, tracking_floor, tune_pid
from piezopreload.tuning.schedule import schedule_levels, tune_schedule
from piezopreload.tuning.validate import ValidationResult
from piezopreload.tuning.verdict import validate_gain_set

__all__ = ["TuningResult", "StudyRun", "tune", "simulate", "reproduce"]

_STEP_KEYS = ("rise_s", "peak_s", "settling_s", "overshoot_N")
_TRACK_KEYS = ("tracking_rms_N", "tracking_max_N")


@dataclass(frozen=True, eq=False)
class TuningResult:
    """Tuned PID gains around a study's compensated rig, compared and bounded; :meth:`validate` judges them.

    ``table`` holds the paper's, SIMC's and the tuned gains on the nominal rig, PID alone and
    with the feedforward; ``minimum_time`` the least settling time any command reaches (the
    tuned over it, ``tuned_over_bound_ratio``); ``tracking_floor`` the trajectory's least RMS
    error any causal controller reaches.
    """

    study: Study
    feedforward: IdentifiedFeedforward
    gains: PIDGains
    simc: PIDGains
    tuning: dict[str, Any]
    table: list[dict[str, Any]]
    minimum_time: dict[str, Any]
    tracking_floor: dict[str, Any]
    improvement: dict[str, float]
    inputs: dict[str, Any]

    def row(self, gains: str = "tuned", feedforward: bool = True) -> dict[str, Any]:
        """One row of the comparison table."""
        return next(r for r in self.table if r["gains"] == gains and r["feedforward"] == feedforward)

    def to_dict(self) -> dict[str, Any]:
        """The tuning artifact's body."""
        criteria = self.study.criteria.to_dict()
        return {
            "gains": gains_to_dict(self.gains), "simc_baseline": gains_to_dict(self.simc), "tuning": self.tuning,
            # how the table was scored (the validation's limits are the validate step's)
            "criteria": {k: criteria[k] for k in ("band_N", "signal", "tracking_after_change_s")},
            "table": self.table, "paper": {"ff+pid": PAPER_RESULTS["ff+pid"]}, "minimum_time": self.minimum_time,
            "tracking_floor": self.tracking_floor, "tracking_improvement": self.improvement, "inputs": self.inputs,
        }

    def save(self, path: str | Path) -> Path:
        write_artifact(path, "tuning", self.to_dict())
        return Path(path)

    @classmethod
    def load(cls, path: str | Path, study: Study, feedforward: IdentifiedFeedforward) -> TuningResult:
        """A tuning artifact read back, for the study and feedforward it was tuned with."""
        doc = read_artifact(path, "tuning")
        try:
            gains, simc = gains_from_dict(doc["gains"]), gains_from_dict(doc["simc_baseline"], "simc_baseline")
            return cls(study, feedforward, gains, simc, doc["tuning"], doc["table"], doc["minimum_time"],
                       doc["tracking_floor"], doc["tracking_improvement"], doc["inputs"])
        except (KeyError, ValueError) as exc:
            raise InputError(f"{path}: field {exc} is missing or invalid; run the tune stage again") from exc

    def candidate(self, inputs: dict[str, Any] | None = None) -> GainSet:
        """The tuned gains as a gain set not yet validated: feedforward, plant, references, criteria and the rig's
        interlock settings of the study's ``[rig_run]``."""
        s, ff = self.study, self.feedforward
        return GainSet(gains=self.gains, status="candidate", feedforward=ff.model, feedforward_info=ff.info(),
                       plant=s.rig, preset=s.name, references={k: s.references[k] for k in REFERENCES},
                       criteria=s.criteria.to_dict(), tuning={**self.tuning, "simc_baseline": gains_to_dict(self.simc)},
                       inputs={"study": s.path, "study_sha256": s.sha256, **(inputs or {})},
                       rig_interlocks=s.rig_run.interlocks(s.rig, s.path))

    def validation(self, *, plants: int | None = None, seed: int | None = None, workers: int | None = None,
                   scheduler: str | None = None, progress: Callable[[str], None] | None = None,
                   bar: Callable[[int, int], None] | None = None,
                   inputs: dict[str, Any] | None = None) -> tuple[GainSet, ValidationResult]:
        """:meth:`validate`, also returning the per-plant result."""
        v = self.study.validation
        plants = v.plants if plants is None else plants
        say = progress or (lambda _m: None)
        say(f"validating on {plants} plants ...")
        return validate_gain_set(self.candidate(inputs), n_plants=plants, seed=(self.study.seed if v.seed is None else v.seed) if seed is None else seed,
                                 workers=v.workers if workers is None else workers, scheduler=scheduler,
                                 progress=bar or (lambda i, n: say(f"  chunk {i}/{n}")))

    def validate(self, plants: int | None = None, seed: int | None = None, *, workers: int | None = None,
                 scheduler: str | None = None, progress: Callable[[str], None] | None = None) -> GainSet:
        """Validate the tuned gains by Monte Carlo on the study's nonlinear rig (``[validation]`` by default):
        a :class:`GainSet`, ``validated`` only if every plant met every criterion. Save it with ``.save()``."""
        return self.validation(plants=plants, seed=seed, workers=workers, scheduler=scheduler, progress=progress)[0]

    def summary(self, gain_set: GainSet, out: str | None = None, seconds: float = 0.0) -> dict[str, Any]:
        """What ``piezopreload tune`` prints: the tuned row with the feedforward as the headline, and the verdict."""
        tuned, paper = self.row("tuned"), self.row("paper")
        return {
            "settling_s": tuned["settling_s"], "settling_measured_s": tuned["settling_measured_s"],
            "overshoot_N": tuned["overshoot_N"], "tracking_rms_N": tuned["tracking_rms_N"],
            "tracking_rms_after_change_N": tuned["tracking_rms_after_change_N"],
            "paper_tracking_rms_N": paper["tracking_rms_N"],
            "paper_tracking_rms_after_change_N": paper["tracking_rms_after_change_N"],
            "lower_bound_settling_s": self.minimum_time["settling_s"],
            "lower_bound_tracking_rms_N": self.tracking_floor["rms_N"],
            "out": out, "status": gain_set.status, "content_sha256": gain_set.content_sha256,
            "gains": gains_to_dict(self.gains), "simc": gains_to_dict(self.simc),
            "tuning": {k: v for k, v in self.tuning.items() if k != "spec"}, "table": self.table,
            "paper": {"ff+pid": PAPER_RESULTS["ff+pid"]}, "minimum_time": self.minimum_time,
            "tracking_improvement": self.improvement, "tracking_floor": self.tracking_floor,
            "validation": gain_set.validation, "seconds": seconds,
            "gain_schedule": self.tuning.get("schedule"),  # the schedule's entries, figures and choice, or None
        }

    def plot(self) -> Any:
        """The comparison table as bars (settling time, tracking RMS): a Figure."""
        from piezopreload.reports import figures  # matplotlib only when drawing

        return figures.gains_comparison(self.table)


def tune(study: Study, feedforward: IdentifiedFeedforward, *, seed: int | None = None,
         progress: Callable[[str], None] | None = None, iterations: Callable[[int], None] | None = None) -> TuningResult:
    """The body of :meth:`Study.tune`: tune, bound, compare (``progress`` gets messages, ``iterations`` IPOPT's count)."""
    say = progress or (lambda _m: None)
    seed = study.seed if seed is None else seed
    spec, criteria, step, trajectory = study.tuning_spec, study.criteria, study.references["step"], study.references["trajectory"]
    say("tuning the PID around the compensated plant (CasADi + IPOPT), the minimum-time bound beside it ...")
    bounding = beside(minimum_time, study.rig, initial_N=float(step.levels_N[0]), final_N=float(step.levels_N[1]),
                      band_N=study.band_N, u_min_V=spec.u_min_V, u_max_V=spec.u_max_V)
    try:
        tuned = tune_pid(study.rig, feedforward.inverse(), spec, progress=iterations)
    except TuningInfeasible as exc:
        bounding.discard()
        raise InfeasibleError(f"{study.path}: {exc}") from exc
    g = tuned.gains
    say(f"tuned in {tuned.seconds:.0f} s: Kc {g.Kc:.4g} V/N, Ti {g.Ti_s:.4g} s, Td {g.Td_s:.4g} s, Tf {g.Tf_s:.4g} s, "
        f"b {g.b:.3g}")
    record: dict[str, Any] = {**tuned.to_dict(), "spec": spec.to_dict()}
    if study.tuning.schedule_levels >= 2:  # a gain schedule on the preload level, or the robust set if it does as well
        span = np.concatenate([study.references[k].levels_N for k in ("step", "trajectory")])
        sched = tune_schedule(study.rig, feedforward.model, spec, criteria, g, step=step, trajectory=trajectory,
                              levels_N=schedule_levels(span.min(), span.max(), study.tuning.schedule_levels),
                              n_plants=study.tuning.schedule_plants, seed=seed, progress=say)
        g, record["schedule"] = sched.gains, sched.to_dict()
    try:
        bound = bounding.result()
    except TuningInfeasible as exc:  # the bound is a comparison, not a requirement: say why it is missing
        say(f"no minimum-time bound: {exc}")
        bound = {"settling_s": None, "reason": str(exc)}
    floor = tracking_floor(study.rig, trajectory)
    say("comparing the paper's, the SIMC and the tuned gains on the nominal rig ...")
    table = compare_gains(study.rig, step, trajectory, {"paper": study.gains, "simc": tuned.baseline, "tuned": g},
                          feedforward.model, criteria, seed)
    row = next(r for r in table if r["gains"] == "tuned" and r["feedforward"])
    settle = row["settling_s"]
    inputs = {"study": study.path, "study_sha256": study.sha256, "seed": seed}
    if feedforward.model_sha256:
        inputs["feedforward_sha256"] = feedforward.model_sha256
    return TuningResult(
        study, feedforward, g, tuned.baseline, record, table,
        {"settling_s": bound["settling_s"], **({"reason": bound["reason"]} if "reason" in bound else {}),
         "tuned_over_bound_ratio": None if settle is None or bound["settling_s"] is None else settle / bound["settling_s"]},
        {**floor, "tuned_over_floor_ratio": row["tracking_rms_N"] / floor["rms_N"]}, tracking_improvement(table),
        inputs)


_STUDY = object()  # step_metrics' default: the study's band and signal


@dataclass(frozen=True, eq=False, kw_only=True)
class StudyRun(ClosedLoopRun):
    """A closed-loop run of one plant, scored as its study says (``band_N``, ``signal``); ``info`` says what ran."""

    band_N: float
    signal: str
    info: dict[str, Any]

    def step_metrics(self, band_N: Any = _STUDY, *, which: int = 1, signal: str | None = None) -> StepMetrics:
        """Rise, peak and settling time and overshoot of the reference's ``which``-th change, in the study's band
        on the study's signal unless given (``band_N=None``: the 10-90 % / 2 % definitions)."""
        m = super().step_metrics(self.band_N if band_N is _STUDY else band_N, which=which, signal=signal or self.signal)
        if not isinstance(m, StepMetrics):  # pragma: no cover - a study's run is one plant
            raise InputError("step_metrics of a batch: index the batch first")
        return m

    def to_dict(self) -> dict[str, Any]:
        """What ``piezopreload simulate --json`` prints: what ran, the step numbers, tracking, the paper's values."""
        numbers = run_numbers(self, self.band_N, self.signal)
        tracking = self.info["reference"] == "trajectory"
        paper: dict[str, Any] = dict.fromkeys(_STEP_KEYS)
        if self.info["reference"] == "step":
            paper.update(PAPER_RESULTS[self.info["controller"]])
        if tracking:
            paper.update(dict.fromkeys(_TRACK_KEYS))
        return {
            **self.info, "reference_levels_N": self.reference.levels_N.tolist(), "band_N": self.band_N,
            "signal": self.signal, "seed": self.seed, "samples": int(self.t_s.size),
            **{k: numbers[k] for k in (*_STEP_KEYS, "peak_command_V", *(_TRACK_KEYS if tracking else ()))},
            "paper": paper,
            "paper_note": ("the paper publishes rise, peak and settling time for the 25 -> 60 N step only "
                           "(Sections 4.2, 4.3); null: not published"),
        }

    def plot(self) -> Any:
        """Reference and force (top), command and amplifier voltage (bottom): a Figure."""
        from piezopreload.reports import figures  # matplotlib only when drawing

        title = f"{self.info['controller'].replace('ff+pid', 'FF + PID').replace('pid', 'PID')}, {self.info['reference']}"
        return figures.closed_loop(self.columns(), self.band_N, self.signal, title)


def simulate(study: Study, gains: GainSet | PIDGains | None, *, controller: str = "ff+pid", reference: str = "step",
             feedforward: IdentifiedFeedforward | None = None, seed: int | None = None) -> StudyRun:
    """The body of :meth:`Study.simulate`."""
    if controller not in CONTROLLERS:
        raise InputError(f"controller must be one of {', '.join(CONTROLLERS)}, got {controller!r}")
    if reference not in REFERENCES:
        raise InputError(f"reference must be one of {', '.join(REFERENCES)}, got {reference!r}")
    if isinstance(gains, GainSet):
        pid, source = gains.gains, {"source": f"gain set {(gains.content_sha256 or '')[:12]}", "status": gains.status}
    elif isinstance(gains, PIDGains):
        pid, source = gains, {"source": "given"}
    else:
        pid, source = study.gains, {"source": f"{study.path} [controller], read as {study.controller.units}"}
    rig = Rig(study.rig)
    inverse, ff_info = None, None
    if controller == "ff+pid":
        if feedforward is None and isinstance(gains, GainSet) and gains.feedforward is not None:
            inverse = gains.feedforward.inverse()
            ff_info = {"source": "the gain set's", "model": gains.feedforward.kind,
                       "operators": gains.feedforward.n_operators}
        else:
            ff = feedforward or study.identify_feedforward()
            inverse, ff_info = ff.inverse(), ff.describe()
    seed = study.seed if seed is None else seed
    run = simulate_loop(rig, Controller(pid, rig.dt_s, inverse), study.references[reference], seed=seed)
    info = {"study": {"path": study.path, "sha256": study.sha256, "name": study.name}, "controller": controller,
            "reference": reference, "gains": {**gains_to_dict(pid), **source}, "feedforward": ff_info,
            "sample_period_s": rig.dt_s}
    return StudyRun(**{f.name: getattr(run, f.name) for f in fields(run)}, band_N=study.band_N, signal=study.signal,
                    info=info)


def reproduce(study: Study, feedforward: IdentifiedFeedforward, *, seed: int | None = None,
              repeats: int = 1) -> dict[str, Any]:
    """The body of :meth:`Study.reproduce`: the paper's six step numbers beside the simulation's, both controllers.

    With ``repeats`` > 1, each number is the median over that many noise realisations, with its range.
    """
    t0 = time.perf_counter()
    if repeats < 1:
        raise InputError(f"repeats: must be >= 1, got {repeats}")
    rep = reproduce_paper(study.rig, study.gains, step=study.references["step"], excitation=study.excitation,
                          seed=study.seed if seed is None else seed, band_N=study.band_N, signal=study.signal,
                          repeats=repeats, feedforward=feedforward.model, feedforward_fit=feedforward.fit)
    return {"study": {"path": study.path, "sha256": study.sha256, "name": study.name},
            "gains": {**gains_to_dict(study.gains), "read_as": study.controller.units}, "band_N": study.band_N,
            "signal": study.signal, **reproduction_summary(rep), "seconds": time.perf_counter() - t0}
