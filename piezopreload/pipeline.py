"""The study pipeline: the steps the CLI runs, each returning a JSON-ready summary."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from piezopreload import __version__
from piezopreload.core.artifacts import ArtifactError, read_artifact, write_artifact
from piezopreload.core.errors import InputError
from piezopreload.core.tables import Record, write_csv
from piezopreload.models.actuator import Rig
from piezopreload.models.closedloop import ClosedLoopRun, simulate
from piezopreload.models.controller import Controller, PIDGains
from piezopreload.models.hysteresis import HysteresisModel, NotInvertibleError, model_from_dict
from piezopreload.study import Study
from piezopreload.tuning.calibrate import PAPER_RESULTS, identify_feedforward, reproduce
from piezopreload.tuning.identify import (
    IdentificationError,
    PIIdentifier,
    fit_error,
    paper_baseline,
    straight_line,
)

__all__ = [
    "Window",
    "parse_window",
    "identify",
    "load_hysteresis_model",
    "load_gains",
    "gains_from_dict",
    "gains_to_dict",
    "simulate_study",
    "reproduce_study",
    "write_run_csv",
    "write_csv",
    "finite_or_none",
    "step_numbers",
]


@dataclass(frozen=True)
class Window:
    """A time window ``[t0_s, t1_s]``."""

    t0_s: float
    t1_s: float

    def as_list(self) -> list[float]:
        return [self.t0_s, self.t1_s]


def parse_window(text: str, option: str) -> Window:
    """``'4:7'`` -> ``Window(4, 7)``; bad text raises :class:`InputError` naming ``option``."""
    a, sep, b = text.partition(":")
    try:
        if not sep:
            raise ValueError
        t0, t1 = float(a), float(b)
    except ValueError:
        raise InputError(f"{option}: '{text}' is not T0:T1 in seconds (example: {option} 4:7)") from None
    if not (np.isfinite(t0) and np.isfinite(t1)) or t1 <= t0:
        raise InputError(f"{option}: '{text}' must have finite T0 < T1")
    return Window(t0, t1)


def identify(
    record: Record,
    *,
    model: str = "classical",
    operators: int = 40,
    train: Window | None = None,
    test: Window | None = None,
    ridge: float = 0.0,
    out: str | Path | None = None,
) -> dict[str, Any]:
    """Identify a hysteresis model on ``train``, score it on ``test``; optionally write the artifact.

    Without windows the first 70 % of the record's duration trains and the rest tests. Errors
    are percentages of the output span of the whole record.
    """
    t0 = time.perf_counter()
    t = record.time_s
    if train is None:
        train = Window(float(t[0]), float(t[0] + 0.7 * (t[-1] - t[0])))
    default_test = test is None
    if default_test:
        test = Window(train.t1_s, float(t[-1]))
    rows = {}
    for name, win in (("train", train), ("test", test)):
        mask = record.window(win.t0_s, win.t1_s)
        if name == "test" and default_test:
            mask &= t > train.t1_s  # the default test window holds only samples after training
        if not mask.any():
            raise InputError(
                f"--{name} {win.t0_s:g}:{win.t1_s:g} holds no samples; the record spans "
                f"{t[0]:g} to {t[-1]:g} s"
            )
        rows[name] = mask
    if np.ptp(record.input[rows["train"]]) == 0:
        raise InputError(
            f"{record.path}: the input '{record.input_name}' is constant over the training window "
            f"{train.t0_s:g}:{train.t1_s:g} s; a hysteresis model needs a varying input"
        )
    span = float(np.ptp(record.output))
    if span == 0:
        raise InputError(f"{record.path}: the output '{record.output_name}' is constant; nothing to model")
    try:
        est = PIIdentifier(model=model, n_operators=operators, ridge=ridge)
        est.fit(record.input, record.output, train=rows["train"])
    except (IdentificationError, ValueError) as exc:
        raise InputError(f"{record.path}: cannot identify a {model} model: {exc}") from None
    predicted = est.predict(record.input)
    v, y = record.input, record.output
    slope, intercept = straight_line(v[rows["train"]], y[rows["train"]])
    try:
        paper = paper_baseline(v, y, est.thresholds_, rows["train"])
        paper_test: dict[str, Any] | None = fit_error(paper(v)[rows["test"]], y[rows["test"]], span)
        paper_note = None
    except IdentificationError as exc:
        paper_test, paper_note = None, str(exc)
    summary: dict[str, Any] = {
        "data": {"path": record.path, "sha256": record.sha256, "samples": int(t.size),
                 "input": record.input_name, "output": record.output_name},
        "model": model,
        "operators": int(est.thresholds_.size),
        "invertible": bool(getattr(est.model_, "invertible", False)),
        "output_span": span,
        "output_unit": record.output_unit,
        "train": {**fit_error(predicted[rows["train"]], y[rows["train"]], span),
                  "window_s": train.as_list(), "samples": int(rows["train"].sum())},
        "test": {**fit_error(predicted[rows["test"]], y[rows["test"]], span),
                 "window_s": test.as_list(), "samples": int(rows["test"].sum())},
        "line_test": {**fit_error(slope * v[rows["test"]] + intercept, y[rows["test"]], span),
                      "slope": slope, "intercept": intercept},
        "paper_method_test": paper_test,
        "solver": {"name": "CLARABEL", "status": est.status_, "polished": est.polished_,
                   "iterations": est.iterations_, "qp_seconds": est.solve_time_s_,
                   "fit_seconds": est.fit_time_s_},
    }
    if paper_note:
        summary["paper_method_note"] = paper_note
    summary["seconds"] = time.perf_counter() - t0
    summary["out"] = None
    if out is not None:
        write_artifact(
            out,
            "hysteresis-model",
            {
                "inputs": {"data": {"path": record.path, "sha256": record.sha256},
                           "train_s": train.as_list(), "test_s": test.as_list()},
                "units": {"input": record.input_unit, "output": record.output_unit,
                          "input_name": record.input_name, "output_name": record.output_name},
                "model": est.model_.to_dict(),
                "identification": {k: summary[k] for k in ("train", "test", "line_test", "solver", "output_span")},
            },
        )
        summary["out"] = str(out)
    return summary


def load_hysteresis_model(path: str | Path) -> tuple[HysteresisModel, dict[str, Any]]:
    """Read a hysteresis-model artifact; errors name the file and field."""
    doc = read_artifact(path, "hysteresis-model")
    try:
        return model_from_dict(doc["model"]), doc
    except ValueError as exc:
        raise ArtifactError(f"{path}: {exc}") from None


# --------------------------------------------------------------------------------------
# simulate and reproduce (the reference rig)
# --------------------------------------------------------------------------------------
CONTROLLER_CHOICES = ("pid", "ff+pid")
REFERENCE_CHOICES = ("step", "trajectory")
_STEP_KEYS = ("rise_s", "peak_s", "settling_s", "overshoot_N")
_TRACK_KEYS = ("tracking_rms_N", "tracking_max_N")


def gains_to_dict(gains: PIDGains) -> dict[str, Any]:
    """The gains in SI with the controller form stated, plus LabVIEW's minutes."""
    return {
        "Kc_V_per_N": gains.Kc, "Ti_s": gains.Ti_s, "Td_s": gains.Td_s, "Tf_s": gains.Tf_s, "b": gains.b,
        "u_min_V": gains.u_min, "u_max_V": gains.u_max,
        "form": "ideal/ISA, trapezoidal integral, derivative on measurement, conditional-integration anti-windup",
        "labview": gains.labview(),
    }


def load_gains(path: str | Path) -> tuple[PIDGains, dict[str, Any]]:
    """Read the gains of a gain-set artifact (SI units); errors name the file and field."""
    doc = read_artifact(path, "gain-set")
    return gains_from_dict(doc["gains"], path), doc


def gains_from_dict(g: Any, path: str | Path, field: str = "gains") -> PIDGains:
    """The inverse of :func:`gains_to_dict`; errors name the file and the field."""
    if not isinstance(g, dict):
        raise ArtifactError(f"{path}: field '{field}' must be an object")
    try:
        missing = next((k for k in ("Kc_V_per_N", "Ti_s", "Td_s") if k not in g), None)
        if missing:
            raise ArtifactError(f"{path}: field '{field}.{missing}' is missing")
        return PIDGains(
            Kc=float(g["Kc_V_per_N"]), Ti_s=float(g["Ti_s"]), Td_s=float(g["Td_s"]),
            Tf_s=float(g.get("Tf_s", 0.0)), b=float(g.get("b", 1.0)),
            u_min=float(g.get("u_min_V", 0.0)), u_max=float(g.get("u_max_V", 110.0)),
        )
    except (TypeError, ValueError) as exc:
        raise ArtifactError(f"{path}: field '{field}' is not valid: {exc}") from None


def _feedforward(study: Study, path: str | Path | None) -> tuple[Any, dict[str, Any]]:
    if path is not None:
        model, doc = load_hysteresis_model(path)
        try:
            inverse = model.inverse()
        except NotInvertibleError as exc:
            raise InputError(f"{path}: the model cannot serve as a feedforward: {exc}") from None
        return inverse, {"source": str(path), "model": model.kind, "operators": model.n_operators}
    model, info = identify_feedforward(Rig(study.rig), study.excitation)
    return model.inverse(), {
        "source": (f"identified from a simulated {study.excitation.v_max_V:g} V, "
                   f"{study.excitation.frequency_Hz:g} Hz loop measurement of the rig"),
        "model": model.kind, "operators": model.n_operators, "fit_rms_pct": info["fit"]["rms_pct"],
        "fit_max_pct": info["fit"]["max_pct"],
    }


def step_numbers(run: ClosedLoopRun, study: Study) -> dict[str, float | None]:
    """Rise, peak and settling time and overshoot of a run, scored as the study says (band, signal)."""
    m = run.step_metrics(study.band_N, signal=study.signal)
    values = {"rise_s": m.rise_s, "peak_s": m.peak_s, "settling_s": m.settling_s, "overshoot_N": m.overshoot}
    return {k: (float(v) if np.isfinite(v) else None) for k, v in values.items()}


def finite_or_none(x: float) -> float | None:
    """``x`` as a float, or None where it is not finite (JSON holds no NaN)."""
    return float(x) if np.isfinite(x) else None


def write_run_csv(path: str | Path, run: ClosedLoopRun, comment: str) -> None:
    """A single-plant run as CSV (one header line, ``#`` comments first), written atomically."""
    write_csv(path, run.columns(), comment)


def simulate_study(
    study: Study,
    *,
    controller: str = "ff+pid",
    reference: str = "step",
    gains_path: str | Path | None = None,
    feedforward_path: str | Path | None = None,
    seed: int | None = None,
    out: str | Path | None = None,
) -> dict[str, Any]:
    """Simulate one controller on the study's rig over one of its references."""
    t0 = time.perf_counter()
    if controller not in CONTROLLER_CHOICES:
        raise InputError(f"controller must be one of {', '.join(CONTROLLER_CHOICES)}, got {controller!r}")
    if reference not in REFERENCE_CHOICES:
        raise InputError(f"reference must be one of {', '.join(REFERENCE_CHOICES)}, got {reference!r}")
    gains, gains_source = study.gains, {"source": f"{study.path} [controller], read as {study.gains_units}"}
    if gains_path is not None:
        gains, doc = load_gains(gains_path)
        gains_source = {"source": str(gains_path), "status": doc.get("status")}
    rig = Rig(study.rig)
    ff, ff_info = (None, None)
    if controller == "ff+pid":
        ff, ff_info = _feedforward(study, feedforward_path)
    seed = study.seed if seed is None else seed
    ref = study.references[reference]
    run = simulate(rig, Controller(gains, rig.dt_s, ff), ref, seed=seed)
    summary: dict[str, Any] = {
        "study": {"path": study.path, "sha256": study.sha256, "name": study.name},
        "controller": controller,
        "reference": reference,
        "reference_levels_N": ref.levels_N.tolist(),
        "gains": {**gains_to_dict(gains), **gains_source},
        "feedforward": ff_info,
        "band_N": study.band_N,
        "signal": study.signal,
        "seed": seed,
        "samples": int(run.t_s.size),
        "sample_period_s": rig.dt_s,
        **step_numbers(run, study),
        "peak_command_V": float(np.max(run.command_V)),
    }
    paper = dict.fromkeys(_STEP_KEYS)
    if reference == "step":
        paper.update(PAPER_RESULTS[controller])
    if reference == "trajectory":
        te = run.tracking_error()
        summary["tracking_rms_N"] = float(te["rms"])
        summary["tracking_max_N"] = float(te["max"])
        paper.update(dict.fromkeys(_TRACK_KEYS))
    summary["paper"] = paper
    summary["paper_note"] = (
        "the paper publishes rise, peak and settling time for the 25 -> 60 N step only (Sections 4.2, 4.3); "
        "null: not published"
    )
    summary["seconds"] = time.perf_counter() - t0
    summary["out"] = None
    if out is not None:
        write_run_csv(out, run, f"piezopreload {__version__} simulate: study {study.name} ({study.sha256[:12]}), "
                                f"controller {controller}, reference {reference}, seed {seed}")
        summary["out"] = str(out)
    return summary


def reproduce_study(study: Study, *, seed: int | None = None, repeats: int = 1) -> dict[str, Any]:
    """The paper's six step numbers beside the simulation's, both controllers, one command.

    With ``repeats`` > 1, each number is the median over that many noise realisations, with
    its range.
    """
    t0 = time.perf_counter()
    rep = reproduce(study.rig, study.gains, step=study.references["step"], excitation=study.excitation,
                    seed=study.seed if seed is None else seed, band_N=study.band_N, signal=study.signal,
                    repeats=repeats)
    rows = [{**r, "within_25pct": bool(abs(r["ratio"] - 1.0) <= 0.25),
             "range": [finite_or_none(x) for x in rep.spread[r["controller"]][r["metric"]]]} for r in rep.table()]
    for r in rows:
        if not np.isfinite(r["simulated"]):
            r.update(simulated=None, ratio=None, within_25pct=False)
    return {
        "study": {"path": study.path, "sha256": study.sha256, "name": study.name},
        "gains": {**gains_to_dict(study.gains), "read_as": study.gains_units},
        "band_N": study.band_N,
        "signal": study.signal,
        "feedforward_fit": rep.feedforward_fit,
        "rows": rows,
        "overshoot_N": {c: rep.metrics[c]["overshoot_N"] for c in rep.metrics},
        "all_within_25pct": all(r["within_25pct"] for r in rows),
        "repeats": repeats,
        "seconds": time.perf_counter() - t0,
    }
