"""A hysteresis model identified from a measured record and checked on a held-out window.

:func:`identify_record` fits a P-I model (:class:`~piezopreload.tuning.identify.PIIdentifier`:
the classical model of eq. (15), the paper's asymmetric one of eq. (18) or Kuhnen's modified
model, each with or without creep) on a training window of a record and scores it on a test
window, beside the best straight line, the paper's own method of eq. (17) and, with creep, the
same model refitted without it. Errors are percentages of the output
span of the whole record. The result saves itself as a ``hysteresis-model`` artifact.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from piezopreload.core.artifacts import write_artifact
from piezopreload.core.errors import InputError
from piezopreload.core.tables import Record
from piezopreload.models.hysteresis import CreepPI, HysteresisModel
from piezopreload.tuning.identify import IdentificationError, PIIdentifier, fit_error, paper_baseline, straight_line

__all__ = ["Window", "HoldoutFit", "identify_record", "WITHOUT_CREEP_HOW"]


@dataclass(frozen=True)
class Window:
    """A time window ``[t0_s, t1_s]``."""

    t0_s: float
    t1_s: float

    def __post_init__(self) -> None:
        if not (np.isfinite(self.t0_s) and np.isfinite(self.t1_s) and self.t0_s < self.t1_s):
            raise InputError(f"a window needs finite t0_s < t1_s, got {self.t0_s!r} and {self.t1_s!r}")

    def as_list(self) -> list[float]:
        return [self.t0_s, self.t1_s]


@dataclass(frozen=True, eq=False)
class HoldoutFit:
    """The identified ``model``, the record it came from and the errors (``summary``: what ``--json`` prints)."""

    model: HysteresisModel | CreepPI
    record: Record
    train: Window
    test: Window
    summary: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        return dict(self.summary)

    def save(self, path: str | Path) -> Path:
        """Write the model as a ``hysteresis-model`` artifact with the record's hash, windows, units and errors."""
        r, s = self.record, self.summary
        write_artifact(path, "hysteresis-model", {
            "inputs": {"data": {"path": r.path, "sha256": r.sha256}, "train_s": self.train.as_list(),
                       "test_s": self.test.as_list()},
            "units": {"input": r.input_unit, "output": r.output_unit, "input_name": r.input_name,
                      "output_name": r.output_name},
            "model": self.model.to_dict(),
            "identification": {k: s[k] for k in ("train", "test", "line_test", "solver", "output_span")},
        })
        return Path(path)

    def plot(self) -> Any:
        """The record and the model's output against the input, train and test windows apart: a Figure."""
        from matplotlib.figure import Figure

        r = self.record
        y = self.model(r.input)
        fig = Figure(figsize=(8.0, 3.2), layout="constrained")
        a, b = fig.subplots(1, 2)
        for ax, win, name in ((a, self.train, "train"), (b, self.test, "test")):
            m = r.window(win.t0_s, win.t1_s)
            ax.plot(r.input[m], r.output[m], color="0.55", lw=0.8, label="measured")
            ax.plot(r.input[m], y[m], "--", lw=1.0, label="model")
            ax.set(xlabel=r.input_name, ylabel=r.output_name, title=f"{name} {win.t0_s:g}-{win.t1_s:g} s")
            ax.legend(fontsize="small")
        return fig


#: why the comparison without creep is a refit, not the creep model with its creep weights zeroed
WITHOUT_CREEP_HOW = ("refit: the same model, operators and windows identified without creep. Zeroing the creep "
                     "weights of the joint fit would also drop the share of the static gain the creep carries, "
                     "scoring a model nobody would use.")


def _sample_period(record: Record) -> float:
    """The record's sample period; creep's lags need a uniformly sampled record."""
    t = record.time_s
    if t.size < 3:
        raise InputError(f"{record.path}: creep needs a record of at least 3 samples, got {t.size}")
    dt = float((t[-1] - t[0]) / (t.size - 1))
    steps = np.diff(t)
    if not dt > 0 or np.max(np.abs(steps - dt)) > 0.01 * dt:
        raise InputError(f"{record.path}: creep needs a uniformly sampled record; its time steps range from "
                         f"{steps.min():.6g} to {steps.max():.6g} s (resample it first)")
    return dt


#: the operators' matrix (samples x operators, float64) an identification may build
MAX_MATRIX_BYTES = 2 * 1024**3


def check_operators(operators: int, n_train: int, n_samples: int, shown: str) -> None:
    """Refuse, before anything is allocated, more operators than the training window or the memory allow.

    The QP needs at least two training samples per weight (the operators' and the linear
    term's), and the operators' outputs over the record are a ``n_samples x operators`` matrix
    of doubles, held to :data:`MAX_MATRIX_BYTES`.
    """
    by_samples = n_train // 2 - 1
    by_memory = MAX_MATRIX_BYTES // (8 * max(n_samples, 1))
    if operators > by_samples:
        raise InputError(f"--operators {operators}: the training window of {shown} has {n_train} samples for "
                         f"{operators + 1} weights; give at least {2 * (operators + 1)} (two per weight): a longer "
                         f"training window, or at most {max(min(by_samples, by_memory), 0)} operators")
    if operators > by_memory:
        raise InputError(f"--operators {operators}: at most {by_memory} for {shown}: the {n_samples} samples' operator "
                         f"matrix would pass {MAX_MATRIX_BYTES / 1024**3:g} GiB; use fewer operators")


def identify_record(record: Record, *, model: str = "classical", operators: int = 40, train: Window | None = None,
                    test: Window | None = None, ridge: float = 0.0, creep: bool = False,
                    creep_time_constants_s: Any = None) -> HoldoutFit:
    """Identify a hysteresis model on ``train`` and score it on ``test``.

    Without windows the first 70 % of the record's duration trains and the rest tests. A model
    name ending in ``+creep`` (or ``creep=True``) adds a bank of creep lags identified in the
    same QP (time constants ``creep_time_constants_s``, one per decade from 10 ms to the
    record's length by default); the summary then also holds the errors of the model refitted
    without creep (``without_creep``, see :data:`WITHOUT_CREEP_HOW`), so the two sit side by side.
    """
    t0 = time.perf_counter()
    if model.endswith("+creep"):
        model, creep = model.removesuffix("+creep"), True
    if creep_time_constants_s is not None and not creep:
        raise InputError("creep time constants were given without creep: add --creep (or a model name ending in +creep)")
    t = record.time_s
    if train is None:
        train = Window(float(t[0]), float(t[0] + 0.7 * (t[-1] - t[0])))
    rows = {}
    for name in ("train", "test"):
        if name == "train":
            win, mask = train, record.window(train.t0_s, train.t1_s)
        elif test is None:  # after the training window, up to the end
            win, mask = Window(train.t1_s, max(float(t[-1]), train.t1_s + 1.0)), t > train.t1_s
        else:
            win, mask = test, record.window(test.t0_s, test.t1_s)
        if not mask.any():
            raise InputError(f"--{name} {win.t0_s:g}:{win.t1_s:g} holds no samples; the record spans "
                             f"{t[0]:g} to {t[-1]:g} s")
        rows[name] = mask
        test = win if name == "test" else test
    if np.ptp(record.input[rows["train"]]) == 0:
        raise InputError(f"{record.path}: the input '{record.input_name}' is constant over the training window "
                         f"{train.t0_s:g}:{train.t1_s:g} s; a hysteresis model needs a varying input")
    span = float(np.ptp(record.output))
    if span == 0:
        raise InputError(f"{record.path}: the output '{record.output_name}' is constant; nothing to model")
    dt = _sample_period(record) if creep else None
    taus = "log" if creep_time_constants_s is None else creep_time_constants_s
    name = model + ("+creep" if creep else "")
    check_operators(operators, int(rows["train"].sum()), record.input.size, f"{record.path}")
    try:
        est = PIIdentifier(model=model, n_operators=operators, ridge=ridge, creep=creep, creep_time_constants_s=taus)
        est.fit(record.input, record.output, train=rows["train"], sample_period_s=dt)
        plain = None
        if creep:
            plain = PIIdentifier(model=model, n_operators=operators, ridge=ridge)
            plain.fit(record.input, record.output, train=rows["train"])
    except (IdentificationError, ValueError) as exc:
        raise InputError(f"{record.path}: cannot identify a {name} model: {exc}") from exc
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
        "model": name,
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
                   "iterations": est.iterations_, "qp_seconds": est.solve_time_s_, "fit_seconds": est.fit_time_s_},
    }
    if plain is not None:
        c = est.model_.creep
        off = plain.predict(record.input)
        summary["creep"] = {"time_constants_s": c.time_constants_s.tolist(), "weights": c.weights.tolist(),
                            "sample_period_s": c.sample_period_s}
        summary["without_creep"] = {"how": WITHOUT_CREEP_HOW, "model": model,
                                    "train": fit_error(off[rows["train"]], y[rows["train"]], span),
                                    "test": fit_error(off[rows["test"]], y[rows["test"]], span)}
    if paper_note:
        summary["paper_method_note"] = paper_note
    summary["seconds"] = time.perf_counter() - t0
    return HoldoutFit(est.model_, record, train, test, summary)
