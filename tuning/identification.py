"""The one way to identify a hysteresis model from a record: :func:`identify`, and its result.

:func:`identify` fits a P-I model with the estimator :class:`~piezopreload.tuning.identify.PIIdentifier`
(the classical model of eq. (15), the paper's asymmetric one of eq. (18) or Kuhnen's modified
model, each with or without creep) on a training window of a record and scores it on a test
window, beside the best straight line, the paper's own method of eq. (17) and, with creep, the
same model refitted without it. Errors are percentages of the output span of the whole record.
The result, :class:`Identification`, shows itself (``repr``, ``_repr_html_``, :meth:`~Identification.plot`)
and saves its model as the ``hysteresis-model`` artifact
(:class:`~piezopreload.artifacts.hysteresis.IdentifiedModel`), the one type of ``model.json``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np
from numpy.typing import NDArray

from piezopreload.artifacts.hysteresis import (
    DataSource,
    FitError,
    IdentifiedModel,
    Refit,
    SolverReport,
    StraightLine,
    Units,
)
from piezopreload.core.errors import InputError
from piezopreload.core.tables import MeasuredRecord
from piezopreload.models.hysteresis import CREEP_SUFFIX, CreepPI, HysteresisModel
from piezopreload.tuning.identify import IdentificationError, PIIdentifier, fit_error, paper_baseline, straight_line

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["Window", "Identification", "identify", "check_operators", "error_rows", "MAX_MATRIX_BYTES"]


@dataclass(frozen=True)
class Window:
    """A time window ``[t0_s, t1_s]``.

    Parameters
    ----------
    t0_s, t1_s : float
        Its start and its end, ``t0_s < t1_s`` (s).
    """

    t0_s: float
    t1_s: float

    def __post_init__(self) -> None:
        if not (np.isfinite(self.t0_s) and np.isfinite(self.t1_s) and self.t0_s < self.t1_s):
            raise InputError(f"a window needs finite t0_s < t1_s, got {self.t0_s!r} and {self.t1_s!r}")

    def as_tuple(self) -> tuple[float, float]:
        """The window as a pair.

        Returns
        -------
        (float, float)
            Its first and last time, in s.
        """
        return (float(self.t0_s), float(self.t1_s))


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


# --------------------------------------------------------------------------------------
# the result
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Identification:
    """A model identified on a record: the artifact's record, the data, the windows and the fitted estimator.

    ``record`` (:class:`~piezopreload.artifacts.hysteresis.IdentifiedModel`) holds the model, its
    errors and where it came from, exactly as :meth:`save` writes them; the other fields are what
    it was computed from.

    Parameters
    ----------
    record : IdentifiedModel
        The artifact's record: the model, its errors on the windows, the data and the solver.
    data : MeasuredRecord
        The measured record it was identified on.
    train : Window
        The window the weights were fitted on.
    test : Window or None
        The window it was scored on (None: scored on the training window only).
    estimator : PIIdentifier
        The fitted estimator (its weights, its solver's report).
    seconds : float
        The wall-clock time the identification took (s).
    """

    record: IdentifiedModel
    data: MeasuredRecord
    train: Window
    test: Window | None
    estimator: PIIdentifier
    seconds: float = 0.0

    @property
    def model(self) -> HysteresisModel | CreepPI:
        """The identified model (input to output)."""
        return self.record.model

    def inverse(self) -> Any:
        """The model's inverse: the feedforward (output -> input).

        Returns
        -------
        InverseClassicalPI, InverseAsymmetricPI, InverseModifiedPI or InverseCreepPI
            A callable from the output to the input.
        """
        return self.record.model.inverse()

    def save(self, path: str | Path) -> IdentifiedModel:
        """Write the model as a ``hysteresis-model`` artifact (the one writer: :meth:`IdentifiedModel.save`).

        Parameters
        ----------
        path : str or Path
            The artifact's file.

        Returns
        -------
        IdentifiedModel
            The record written, its hash set.
        """
        return self.record.save(path)

    def to_dict(self) -> dict[str, Any]:
        """What ``piezopreload identify --json`` prints.

        Returns
        -------
        dict
            ``data`` (path, hash, samples, columns), the model's kind and operators, whether it is invertible, the
            output's span, range and unit, the fit on the ``train`` and the ``test`` window, the solver's figures,
            ``seconds``, and the creep's lags and the fit without creep where they apply.
        """
        r, d, sv = self.record, self.data, self.record.solver
        out: dict[str, Any] = {
            "data": {"path": d.path, "sha256": d.sha256, "samples": int(d.time_s.size), "input": d.input_name,
                     "output": d.output_name},
            "model": r.model.kind, "operators": r.model.n_operators, "invertible": bool(r.model.invertible),
            "output_span": r.output_span, "output_range": list(r.output_range), "output_unit": r.units.output,
            "train": r.fit.to_dict(), "test": None if r.test is None else r.test.to_dict(),
            "line_test": None if r.line is None else r.line.to_dict(),
            "paper_method_test": None if r.paper_method_test is None else r.paper_method_test.to_dict(),
            "solver": sv.to_dict(), "seconds": self.seconds,
        }
        if isinstance(r.model, CreepPI):
            out["creep"] = r.model.creep.to_dict()
        if r.without_creep is not None:
            w = r.without_creep
            out["without_creep"] = {"how": w.to_dict()["how"], "model": w.model.kind, "train": w.fit.to_dict(),
                                    "test": None if w.test is None else w.test.to_dict()}
        if r.paper_method_note:
            out["paper_method_note"] = r.paper_method_note
        return out

    def _rows(self) -> list[tuple[str, FitError]]:
        return error_rows(self.record)

    def _title(self) -> str:
        m, d = self.record.model, self.data
        return (f"{m.kind} P-I model, {m.n_operators} play operators, {'' if m.invertible else 'not '}invertible; "
                f"{Path(d.path).name or 'record'} ({d.time_s.size} samples, {d.input_name} -> {d.output_name})")

    def __repr__(self) -> str:
        span = f"{self.record.output_span:.4g} {self.record.units.output}"
        lines = [f"Identification({self._title()})", f"  errors in % of the output span ({span}): RMS, max"]
        lines += [f"  {label:40s}{e.rms_pct:8.3f}{e.max_pct:8.3f}" for label, e in self._rows()]
        return "\n".join(lines)

    def _repr_html_(self) -> str:
        from html import escape

        rows = "".join(f"<tr><td>{escape(label)}</td><td>{e.rms_pct:.3f}</td><td>{e.max_pct:.3f}</td></tr>"
                       for label, e in self._rows())
        return (f"<p><b>Identification</b>: {escape(self._title())}</p><table><thead><tr><th>window</th>"
                f"<th>RMS (% of {self.record.output_span:.4g} {escape(self.record.units.output)})</th><th>max (%)</th>"
                f"</tr></thead><tbody>{rows}</tbody></table>")

    def plot(self) -> Figure:
        """The record and the model's output against the input, on the training and the test window: a Figure.

        Returns
        -------
        matplotlib.figure.Figure
            One panel per window (training, test): the record's and the model's output against the input.
        """
        from matplotlib.figure import Figure

        d = self.data
        y = self.estimator.predict(d.input)
        windows = [("train", self.train)] + ([("test", self.test)] if self.test is not None else [])
        fig = Figure(figsize=(4.0 * len(windows), 3.2), layout="constrained")
        axes = np.atleast_1d(fig.subplots(1, len(windows)))
        for ax, (name, win) in zip(axes, windows):
            m = d.window(win.t0_s, win.t1_s)
            ax.plot(d.input[m], d.output[m], color="0.55", lw=0.8, label="record")
            ax.plot(d.input[m], y[m], "--", lw=1.0, label=f"{self.record.model.kind} model")
            ax.set(xlabel=d.input_name, ylabel=d.output_name, title=f"{name} {win.t0_s:g}-{win.t1_s:g} s")
            ax.legend(fontsize="small")
        return fig


def error_rows(r: IdentifiedModel) -> list[tuple[str, FitError]]:
    """The fit's errors as a table's rows ``(label, error)``: training, test, the straight line and the paper's
    method on the test, the model without creep on the test (each where it was fitted).

    Parameters
    ----------
    r : IdentifiedModel
        The identified model's record.

    Returns
    -------
    list of (str, FitError)
        The rows, in that order.
    """
    rows = [(f"train {_window(r.fit)}", r.fit)]
    if r.test is not None:
        rows.append((f"test {_window(r.test)}", r.test))
    if r.line is not None:
        rows.append(("test, best straight line", r.line.test))
    if r.paper_method_test is not None:
        rows.append(("test, the paper's method (eq. 17)", r.paper_method_test))
    if r.without_creep is not None and r.without_creep.test is not None:
        rows.append((f"test, {r.without_creep.model.kind} without creep", r.without_creep.test))
    return rows


def _window(e: FitError) -> str:
    return "" if e.window_s is None else f"{e.window_s[0]:g}-{e.window_s[1]:g} s"


# --------------------------------------------------------------------------------------
# the entry point
# --------------------------------------------------------------------------------------
def _windows(record: MeasuredRecord, train: Window | None, test: Window | None
             ) -> tuple[Window, NDArray[np.bool_], Window | None, NDArray[np.bool_] | None]:
    """The training and test windows and their samples; without a test window, the samples after training."""
    t = record.time_s
    train = train or Window(float(t[0]), float(t[0] + 0.7 * (t[-1] - t[0])))
    rows = record.window(train.t0_s, train.t1_s)
    if not rows.any():
        raise InputError(f"--train {train.t0_s:g}:{train.t1_s:g} holds no samples; the record spans "
                         f"{t[0]:g} to {t[-1]:g} s")
    if test is not None:
        test_rows = record.window(test.t0_s, test.t1_s)
        if not test_rows.any():
            raise InputError(f"--test {test.t0_s:g}:{test.t1_s:g} holds no samples; the record spans "
                             f"{t[0]:g} to {t[-1]:g} s")
        return train, rows, test, test_rows
    after = t > train.t1_s
    if not after.any():  # trained on all of it: nothing held out
        return train, rows, None, None
    return train, rows, Window(train.t1_s, max(float(t[-1]), train.t1_s + 1.0)), after


def _sample_period(record: MeasuredRecord) -> float:
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


def _check_record(record: MeasuredRecord, rows: NDArray[np.bool_], train: Window) -> float:
    """The record's output span; refuses a constant input over the training window or a constant output."""
    if np.ptp(record.input[rows]) == 0:
        raise InputError(f"{record.path}: the input '{record.input_name}' is constant over the training window "
                         f"{train.t0_s:g}:{train.t1_s:g} s; a hysteresis model needs a varying input")
    span = float(np.ptp(record.output))
    if span == 0:
        raise InputError(f"{record.path}: the output '{record.output_name}' is constant; nothing to model")
    return span


class _Baselines(TypedDict, total=False):
    """The baselines' fields of an :class:`IdentifiedModel` (its keywords): the straight line's errors, the paper's
    method's held-out error or why it cannot run."""

    line: StraightLine
    paper_method_test: FitError
    paper_method_note: str


def _baselines(record: MeasuredRecord, est: PIIdentifier, rows: NDArray[np.bool_], test_rows: NDArray[np.bool_] | None,
               span: float) -> _Baselines:
    """The straight line's and the paper's method's errors on the test window (the paper's: or why it cannot run)."""
    if test_rows is None:
        return _Baselines()
    v, y = record.input, record.output
    slope, intercept = straight_line(v[rows], y[rows])
    out = _Baselines(line=StraightLine(slope, intercept, fit_error(slope * v[test_rows] + intercept, y[test_rows],
                                                                  span)))
    try:
        paper = paper_baseline(v, y, est.thresholds_, rows)
        out["paper_method_test"] = fit_error(paper(v)[test_rows], y[test_rows], span)
    except IdentificationError as exc:
        out["paper_method_note"] = str(exc)
    return out


def identify(record: MeasuredRecord, *, model: str = "classical", operators: int = 40, thresholds: Any = "range",
             train: Window | None = None, test: Window | None = None, ridge: float = 0.0, creep: bool = False,
             creep_time_constants_s: Any = None, invertible: bool = False, baselines: bool = True,
             source: DataSource | None = None) -> Identification:
    """Identify a hysteresis model on ``train`` and score it on ``test``: the one entry point.

    Parameters
    ----------
    record : MeasuredRecord
        The input/output record (:func:`piezopreload.read_record`).
    model : str
        ``classical``, ``paper-asymmetric`` or ``modified``; a name ending in ``+creep`` is ``creep=True``.
    operators, thresholds, ridge, invertible
        As :class:`~piezopreload.tuning.identify.PIIdentifier` (``n_operators``, ...).
    train, test : Window, optional
        Without ``train`` the first 70 % of the record's duration trains; without ``test`` the
        samples after the training window test (none: nothing is held out).
    creep, creep_time_constants_s
        A bank of creep lags identified in the same QP (one per decade from 10 ms to the
        record's length by default); the result then also holds the model refitted without creep.
    baselines : bool
        Score the best straight line and the paper's method (eq. (17)) on the test window beside the model.
    source : DataSource, optional
        Where the record came from (default: the measured file ``record.path``).

    Returns
    -------
    Identification
    """
    t0 = time.perf_counter()
    if model.endswith(CREEP_SUFFIX):
        model, creep = model.removesuffix(CREEP_SUFFIX), True
    if creep_time_constants_s is not None and not creep:
        raise InputError("creep time constants were given without creep: "
                         "add --creep (or a model name ending in +creep)")
    train, rows, test, test_rows = _windows(record, train, test)
    span = _check_record(record, rows, train)
    dt = _sample_period(record) if creep else None
    check_operators(operators, int(rows.sum()), record.input.size, f"{record.path}")
    name = model + (CREEP_SUFFIX if creep else "")
    options = {"model": model, "n_operators": operators, "thresholds": thresholds, "ridge": ridge,
               "invertible": invertible}
    v, y = record.input, record.output
    try:
        est = PIIdentifier(**options, creep=creep, creep_time_constants_s="log" if creep_time_constants_s is None
                           else creep_time_constants_s).fit(v, y, train=rows, sample_period_s=dt)
        plain = PIIdentifier(**options).fit(v, y, train=rows) if creep else None
    except (IdentificationError, ValueError) as exc:
        raise InputError(f"{record.path}: cannot identify a {name} model: {exc}") from exc

    def errors(fitted: PIIdentifier, mask: NDArray[np.bool_], win: Window) -> FitError:
        return fit_error(fitted.predict(v)[mask], y[mask], span, win.as_tuple())

    held_out = test_rows is not None and test is not None
    ident = IdentifiedModel(
        model=est.model_, data=source or DataSource("measured", record.sha256, record.path),
        units=Units(record.input_unit, record.output_unit, record.input_name, record.output_name),
        output_span=span, output_range=(float(np.min(y[rows])), float(np.max(y[rows]))), fit=errors(est, rows, train),
        solver=SolverReport(est.status_, bool(est.polished_), int(est.iterations_), float(est.solve_time_s_),
                            float(est.fit_time_s_)),
        test=errors(est, test_rows, test) if held_out else None,  # type: ignore[arg-type]
        without_creep=None if plain is None else Refit(
            plain.model_, errors(plain, rows, train),  # type: ignore[arg-type]
            errors(plain, test_rows, test) if held_out else None),  # type: ignore[arg-type]
        **(_baselines(record, est, rows, test_rows, span) if baselines else _Baselines()))
    return Identification(ident, record, train, test, est, time.perf_counter() - t0)

