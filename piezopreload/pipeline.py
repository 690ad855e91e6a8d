"""The study pipeline: the steps the CLI runs, each returning a JSON-ready summary."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from piezopreload.artifacts import ArtifactError, read_artifact, write_artifact
from piezopreload.io import InputError, Record
from piezopreload.models.hysteresis import HysteresisModel, model_from_dict
from piezopreload.tuning.identify import (
    IdentificationError,
    PIIdentifier,
    fit_error,
    paper_baseline,
    straight_line,
)

__all__ = ["Window", "parse_window", "identify", "load_hysteresis_model"]


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
