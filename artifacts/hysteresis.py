"""The identified hysteresis model (``model.json``): one type, one writer, one reader.

A P-I model (:mod:`piezopreload.models.hysteresis`) with where it came from and how well it
fits: the record it was identified on (a measured file or a loop simulated on a rig, with its
SHA-256), the units of its input and output, the output range it was identified over (a
feedforward is only asked for forces inside it), its errors on the training and test windows in
% of the record's output span beside a straight line and the paper's own method, the solver's
report, the same model refitted without creep where it has creep, and, for a study's
feedforward, the open-loop compensation check. :meth:`IdentifiedModel.save` is the one writer
and :meth:`IdentifiedModel.load` the one reader of the artifact kind ``hysteresis-model``.

The document's layout::

    {"inputs": {"data": {"kind", "sha256", "path"?, "excitation"?}, ...hashes},
     "units": {"input", "output", "input_name", "output_name"},
     "model": {...the model's to_dict()...},
     "identification": {"output_span", "output_range", "fit", "test", "line_test", "paper_method_test",
                        "paper_method_note", "solver", "without_creep", "compensation_rms_N",
                        "compensation_max_N"}}

``fit`` holds the errors on the training window (for a study's feedforward, the whole loop).
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from piezopreload.core.artifacts import read_artifact, write_artifact
from piezopreload.core.errors import ArtifactError, InputError
from piezopreload.models.hysteresis import CreepPI, HysteresisModel, model_from_dict

__all__ = ["KIND", "FitError", "DataSource", "Units", "SolverReport", "StraightLine", "Refit", "Compensation",
           "IdentifiedModel", "require_coverage", "COVERAGE_MARGIN", "WITHOUT_CREEP_HOW"]

KIND = "hysteresis-model"
_SOURCES = ("simulated", "measured")


# --------------------------------------------------------------------------------------
# field readers: each names the field that is missing or wrong
# --------------------------------------------------------------------------------------
def _get(doc: Any, key: str, where: str) -> Any:
    if not isinstance(doc, dict):
        raise ArtifactError(f"field '{where}' must be an object, got {type(doc).__name__}")
    if key not in doc:
        raise ArtifactError(f"field '{where}.{key}' is missing")
    return doc[key]


def _number(x: Any, where: str) -> float:
    if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
        raise ArtifactError(f"field '{where}' must be a finite number, got {x!r}")
    return float(x)


def _text(x: Any, where: str) -> str:
    if not isinstance(x, str):
        raise ArtifactError(f"field '{where}' must be text, got {x!r}")
    return x


def _pair(x: Any, where: str) -> tuple[float, float]:
    if not isinstance(x, list | tuple) or len(x) != 2:
        raise ArtifactError(f"field '{where}' must be a pair [low, high], got {x!r}")
    return _number(x[0], f"{where}[0]"), _number(x[1], f"{where}[1]")


def _mapping(x: Any, where: str) -> dict[str, Any]:
    if not isinstance(x, dict):
        raise ArtifactError(f"field '{where}' must be an object, got {type(x).__name__}")
    return dict(x)


def _optional(doc: dict[str, Any], key: str, read: Any, where: str) -> Any:
    return None if doc.get(key) is None else read(doc[key], f"{where}.{key}")


def _check(ok: bool, message: str) -> None:
    if not ok:
        raise InputError(message)


# --------------------------------------------------------------------------------------
# the parts
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FitError:
    """A model's error on a window of its record, in % of the record's output span (RMS and largest)."""

    rms_pct: float
    max_pct: float
    window_s: tuple[float, float] | None = None
    samples: int | None = None

    def __post_init__(self) -> None:
        _check(math.isfinite(self.rms_pct) and math.isfinite(self.max_pct) and 0 <= self.rms_pct <= self.max_pct
               + 1e-12 * abs(self.max_pct), f"FitError needs finite 0 <= rms_pct <= max_pct, got {self.rms_pct!r}, "
               f"{self.max_pct!r}.")

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"rms_pct": self.rms_pct, "max_pct": self.max_pct}
        if self.window_s is not None:
            out["window_s"] = list(self.window_s)
        if self.samples is not None:
            out["samples"] = self.samples
        return out

    @classmethod
    def from_dict(cls, doc: Any, where: str = "fit") -> FitError:
        window = _optional(doc, "window_s", _pair, where) if isinstance(doc, dict) else None
        samples = doc.get("samples") if isinstance(doc, dict) else None
        if samples is not None and (isinstance(samples, bool) or not isinstance(samples, int) or samples < 1):
            raise ArtifactError(f"field '{where}.samples' must be a whole number >= 1, got {samples!r}")
        try:
            return cls(_number(_get(doc, "rms_pct", where), f"{where}.rms_pct"),
                       _number(_get(doc, "max_pct", where), f"{where}.max_pct"), window, samples)
        except InputError as exc:
            raise ArtifactError(f"field '{where}': {exc}") from None


@dataclass(frozen=True)
class DataSource:
    """Where the record came from: ``measured`` (a file, ``path``) or ``simulated`` (a loop on a rig, ``excitation``).

    ``sha256`` is the file's, or for a simulated loop that of its samples (float64, time, input and
    output one after the other).
    """

    kind: str
    sha256: str
    path: str | None = None
    excitation: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        _check(self.kind in _SOURCES, f"DataSource.kind must be one of {', '.join(_SOURCES)}, got {self.kind!r}.")
        _check(isinstance(self.sha256, str) and len(self.sha256) == 64,
               f"DataSource.sha256 must be a SHA-256 in hex, got {self.sha256!r}.")

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": self.kind, "sha256": self.sha256}
        if self.path is not None:
            out["path"] = self.path
        if self.excitation is not None:
            out["excitation"] = dict(self.excitation)
        return out

    @classmethod
    def from_dict(cls, doc: Any, where: str = "inputs.data") -> DataSource:
        excitation = _optional(doc, "excitation", _mapping, where) if isinstance(doc, dict) else None
        try:
            return cls(_text(_get(doc, "kind", where), f"{where}.kind"), _text(_get(doc, "sha256", where),
                       f"{where}.sha256"), _optional(doc, "path", _text, where), excitation)
        except InputError as exc:
            raise ArtifactError(f"field '{where}': {exc}") from None


@dataclass(frozen=True)
class Units:
    """The model's input and output: their units and the record's column names."""

    input: str = "V"
    output: str = "N"
    input_name: str = "voltage_V"
    output_name: str = "force_N"

    def to_dict(self) -> dict[str, Any]:
        return {"input": self.input, "output": self.output, "input_name": self.input_name,
                "output_name": self.output_name}

    @classmethod
    def from_dict(cls, doc: Any, where: str = "units") -> Units:
        return cls(*(_text(_get(doc, k, where), f"{where}.{k}") for k in ("input", "output", "input_name",
                                                                              "output_name")))


@dataclass(frozen=True)
class SolverReport:
    """The QP's report: Clarabel's status, whether the active-set polish was kept, iterations and times."""

    status: str
    polished: bool
    iterations: int
    qp_seconds: float
    fit_seconds: float
    name: str = "CLARABEL"

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "status": self.status, "polished": self.polished, "iterations": self.iterations,
                "qp_seconds": self.qp_seconds, "fit_seconds": self.fit_seconds}

    @classmethod
    def from_dict(cls, doc: Any, where: str = "identification.solver") -> SolverReport:
        polished, iterations = _get(doc, "polished", where), _get(doc, "iterations", where)
        if not isinstance(polished, bool):
            raise ArtifactError(f"field '{where}.polished' must be true or false, got {polished!r}")
        if isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < 0:
            raise ArtifactError(f"field '{where}.iterations' must be a whole number >= 0, got {iterations!r}")
        return cls(_text(_get(doc, "status", where), f"{where}.status"), polished, iterations,
                   _number(_get(doc, "qp_seconds", where), f"{where}.qp_seconds"),
                   _number(_get(doc, "fit_seconds", where), f"{where}.fit_seconds"),
                   _text(doc.get("name", "CLARABEL"), f"{where}.name"))


@dataclass(frozen=True)
class StraightLine:
    """The least-squares line ``output = slope * input + intercept`` on the training window, and its test error."""

    slope: float
    intercept: float
    test: FitError

    def to_dict(self) -> dict[str, Any]:
        return {**self.test.to_dict(), "slope": self.slope, "intercept": self.intercept}

    @classmethod
    def from_dict(cls, doc: Any, where: str = "identification.line_test") -> StraightLine:
        return cls(_number(_get(doc, "slope", where), f"{where}.slope"),
                   _number(_get(doc, "intercept", where), f"{where}.intercept"), FitError.from_dict(doc, where))


#: why the comparison without creep is a refit, not the creep model with its creep weights zeroed
WITHOUT_CREEP_HOW = ("refit: the same model, operators and windows identified without creep. Zeroing the creep "
                     "weights of the joint fit would also drop the share of the static gain the creep carries, "
                     "scoring a model nobody would use.")


@dataclass(frozen=True, eq=False)
class Refit:
    """A model with creep refitted without it (:data:`WITHOUT_CREEP_HOW`): the model and its errors."""

    model: HysteresisModel
    fit: FitError
    test: FitError | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"how": WITHOUT_CREEP_HOW, "model": self.model.to_dict(), "fit": self.fit.to_dict(),
                "test": None if self.test is None else self.test.to_dict()}

    @classmethod
    def from_dict(cls, doc: Any, where: str = "identification.without_creep") -> Refit:
        model = _model(_get(doc, "model", where), f"{where}.model")
        if isinstance(model, CreepPI):
            raise ArtifactError(f"field '{where}.model.kind' is '{model.kind}': the refit has no creep")
        return cls(model, FitError.from_dict(_get(doc, "fit", where), f"{where}.fit"),
                   _optional(doc, "test", FitError.from_dict, where))


@dataclass(frozen=True)
class Compensation:
    """The rig driven through the model's inverse in open loop: the force's error against the desired one."""

    rms_N: float
    max_N: float


def _model(doc: Any, where: str) -> HysteresisModel | CreepPI:
    try:
        return model_from_dict(doc, where)
    except ValueError as exc:
        raise ArtifactError(f"field {exc}") from None


# --------------------------------------------------------------------------------------
# the record
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class IdentifiedModel:
    """An identified P-I model and its record (see the module docstring); frozen, checked on construction.

    Parameters
    ----------
    model : HysteresisModel or CreepPI
        The identified model.
    data : DataSource
        The record it was identified on.
    units : Units
        The model's input and output.
    output_span : float
        ``max - min`` of the record's output: what the errors are percentages of.
    output_range : (float, float)
        The output's least and largest value over the training window: the range the model was
        identified over.
    fit : FitError
        The error on the training window.
    solver : SolverReport
        The QP's report.
    test, line, paper_method_test, paper_method_note, without_creep, compensation
        The held-out error, the straight line's, the paper's method's (or why it could not
        run), the refit without creep, the open-loop compensation check; None where they were
        not made.
    inputs : dict
        Hashes of what else it came from (the study, say).
    file_sha256 : str or None
        SHA-256 of the file it was read from or written to.
    """

    model: HysteresisModel | CreepPI
    data: DataSource
    units: Units
    output_span: float
    output_range: tuple[float, float]
    fit: FitError
    solver: SolverReport
    test: FitError | None = None
    line: StraightLine | None = None
    paper_method_test: FitError | None = None
    paper_method_note: str | None = None
    without_creep: Refit | None = None
    compensation: Compensation | None = None
    inputs: dict[str, Any] = field(default_factory=dict)
    file_sha256: str | None = None

    def __post_init__(self) -> None:
        _check(callable(getattr(self.model, "to_dict", None)) and hasattr(self.model, "kind"),
               f"IdentifiedModel.model must be a P-I model, got {type(self.model).__name__}.")
        _check(math.isfinite(self.output_span) and self.output_span > 0,
               f"IdentifiedModel.output_span must be > 0, got {self.output_span!r}.")
        lo, hi = self.output_range
        _check(math.isfinite(lo) and math.isfinite(hi) and lo <= hi,
               f"IdentifiedModel.output_range must be finite with low <= high, got {self.output_range!r}.")
        object.__setattr__(self, "output_range", (float(lo), float(hi)))

    # ---- the document ------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The artifact's body (what :meth:`save` writes inside the envelope)."""
        ident: dict[str, Any] = {
            "output_span": self.output_span, "output_range": list(self.output_range), "fit": self.fit.to_dict(),
            "test": None if self.test is None else self.test.to_dict(),
            "line_test": None if self.line is None else self.line.to_dict(),
            "paper_method_test": None if self.paper_method_test is None else self.paper_method_test.to_dict(),
            "paper_method_note": self.paper_method_note, "solver": self.solver.to_dict(),
            "without_creep": None if self.without_creep is None else self.without_creep.to_dict(),
            "compensation_rms_N": None if self.compensation is None else self.compensation.rms_N,
            "compensation_max_N": None if self.compensation is None else self.compensation.max_N}
        return {"inputs": {"data": self.data.to_dict(), **self.inputs}, "units": self.units.to_dict(),
                "model": self.model.to_dict(), "identification": ident}

    @classmethod
    def from_dict(cls, doc: dict[str, Any], shown: str = "the hysteresis model") -> IdentifiedModel:
        """The inverse of :meth:`to_dict`; an :class:`ArtifactError` names ``shown`` and the field."""
        try:
            return cls._from_dict(doc)
        except ArtifactError as exc:
            raise ArtifactError(f"{shown}: {exc}") from None
        except InputError as exc:
            raise ArtifactError(f"{shown}: {exc}") from None

    @classmethod
    def _from_dict(cls, doc: dict[str, Any]) -> IdentifiedModel:
        inputs, ident = _get(doc, "inputs", "document"), _get(doc, "identification", "document")
        if not isinstance(ident, dict):
            raise ArtifactError(f"field 'identification' must be an object, got {type(ident).__name__}")
        w = "identification"
        comp = None
        if ident.get("compensation_rms_N") is not None:
            comp = Compensation(_number(ident["compensation_rms_N"], f"{w}.compensation_rms_N"),
                                _number(_get(ident, "compensation_max_N", w), f"{w}.compensation_max_N"))
        note = _optional(ident, "paper_method_note", _text, w)
        return cls(
            model=_model(_get(doc, "model", "document"), "model"),
            data=DataSource.from_dict(_get(inputs, "data", "inputs")),
            units=Units.from_dict(_get(doc, "units", "document")),
            output_span=_number(_get(ident, "output_span", w), f"{w}.output_span"),
            output_range=_pair(_get(ident, "output_range", w), f"{w}.output_range"),
            fit=FitError.from_dict(_get(ident, "fit", w), f"{w}.fit"),
            solver=SolverReport.from_dict(_get(ident, "solver", w)),
            test=_optional(ident, "test", FitError.from_dict, w),
            line=_optional(ident, "line_test", StraightLine.from_dict, w),
            paper_method_test=_optional(ident, "paper_method_test", FitError.from_dict, w),
            paper_method_note=note,
            without_creep=_optional(ident, "without_creep", Refit.from_dict, w),
            compensation=comp,
            inputs={k: v for k, v in inputs.items() if k != "data"})

    # ---- the artifact: one reader, one writer ---------------------------------------------------
    @classmethod
    def load(cls, path: str | Path) -> IdentifiedModel:
        """Read a ``hysteresis-model`` artifact: schema and every field checked; errors name the file and field."""
        doc = read_artifact(path, KIND)
        digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()
        return replace(cls.from_dict(doc, str(path)), file_sha256=digest)

    def save(self, path: str | Path) -> IdentifiedModel:
        """Write atomically; returns the record with the written file's SHA-256."""
        write_artifact(path, KIND, self.to_dict())
        return replace(self, file_sha256=hashlib.sha256(Path(path).read_bytes()).hexdigest())

    # ---- what it says ---------------------------------------------------------------------------
    def covers(self, low: float, high: float, what: str = "the references") -> None:
        """Refuse (an :class:`InputError` naming both ranges) outputs ``[low, high]`` the model was not identified
        over: :func:`require_coverage`."""
        shown = f"{self.data.kind} {self.units.output_name}" + ("" if self.data.path is None
                                                                else f" of {self.data.path}")
        require_coverage(self.output_range, (low, high), what, unit=self.units.output, source=shown)


#: how far past its identified range a model may be asked for, as a share of that range's span
COVERAGE_MARGIN = 0.25


def require_coverage(identified: tuple[float, float], wanted: tuple[float, float], what: str, *, unit: str = "N",
                     source: str = "") -> None:
    """Refuse (an :class:`InputError`) a range ``wanted`` of outputs beyond the range a model was identified over.

    Past the top of its range every play operator moves with the input, so the model goes on
    along the loop's outer slope: a short extrapolation, as the paper's own study makes (its
    0-100 V loop reaches 91 N on the simulated rig, its staircase 100 N, 13 % of the loop's span
    beyond). A range reaching past the identified one by up to :data:`COVERAGE_MARGIN` of its
    span is accepted; farther (a loop of 0-79 N for a plant driven to 4,900 N, say), the inverse
    would extrapolate a loop it has not seen. The message names both ranges.
    """
    (lo, hi), (low, high) = identified, wanted
    margin = COVERAGE_MARGIN * (hi - lo)
    if low < lo - margin or high > hi + margin:
        raise InputError(
            f"the feedforward's P-I model is identified over {lo:,.4g} to {hi:,.4g} {unit}"
            f"{f' ({source})' if source else ''}, but {what} span {low:,.4g} to {high:,.4g} {unit}: identify it on "
            "a loop that covers them (a larger [feedforward] v_max_V, or a loop measured over the plant's range)")
