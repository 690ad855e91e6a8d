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
from dataclasses import replace
from pathlib import Path
from typing import Any, ClassVar

from piezopreload.core.errors import InputError
from piezopreload.core.records import Artifact, Record, entry, object_without, record
from piezopreload.models.hysteresis import CreepPI, HysteresisModel, model_from_dict

__all__ = ["KIND", "FitError", "DataSource", "Units", "SolverReport", "StraightLine", "Refit", "Compensation",
           "IdentifiedModel", "require_coverage", "COVERAGE_MARGIN", "WITHOUT_CREEP_HOW"]

KIND = "hysteresis-model"
_SOURCES = ("simulated", "measured")


def _check(ok: bool, message: str) -> None:
    if not ok:
        raise InputError(message)


def _model_from(doc: Any) -> HysteresisModel | CreepPI:
    return model_from_dict(doc)


# --------------------------------------------------------------------------------------
# the parts
# --------------------------------------------------------------------------------------
@record
class FitError(Record):
    """A model's error on a window of its record, in % of the record's output span."""

    rms_pct: float = entry("The RMS error.", unit="%")
    max_pct: float = entry("The largest error.", unit="%")
    window_s: tuple[float, float] | None = entry("The window (from, to) it was scored on.", unit="s", default=None,
                                                 omit=True)
    samples: int | None = entry("The samples in the window.", ge=1, default=None, omit=True)

    def __post_init__(self) -> None:
        _check(math.isfinite(self.rms_pct) and math.isfinite(self.max_pct) and 0 <= self.rms_pct <= self.max_pct
               + 1e-12 * abs(self.max_pct), f"FitError needs finite 0 <= rms_pct <= max_pct, got {self.rms_pct!r}, "
               f"{self.max_pct!r}.")


@record
class DataSource(Record):
    """Where the record came from: ``measured`` (a file, ``path``) or ``simulated`` (a loop on a rig, ``excitation``).

    ``sha256`` is the file's, or for a simulated loop that of its samples (float64, time, input and
    output one after the other).
    """

    kind: str = entry("``measured`` or ``simulated``.", choices=_SOURCES)
    sha256: str = entry("The SHA-256 of the file, or of a simulated loop's samples.")
    path: str | None = entry("The measured file.", default=None, omit=True)
    excitation: dict[str, Any] | None = entry("How the simulated loop was driven.", default=None, omit=True)

    def __post_init__(self) -> None:
        _check(self.kind in _SOURCES, f"DataSource.kind must be one of {', '.join(_SOURCES)}, got {self.kind!r}.")
        _check(isinstance(self.sha256, str) and len(self.sha256) == 64,
               f"DataSource.sha256 must be a SHA-256 in hex, got {self.sha256!r}.")


@record
class Units(Record):
    """The model's input and output: their units and the record's column names."""

    input: str = entry("The input's unit.", default="V", required=True)
    output: str = entry("The output's unit.", default="N", required=True)
    input_name: str = entry("The record's input column.", default="voltage_V", required=True)
    output_name: str = entry("The record's output column.", default="force_N", required=True)


@record
class SolverReport(Record):
    """The QP's report: Clarabel's status, whether the active-set polish was kept, iterations and times."""

    status: str = entry("The solver's status.")
    polished: bool = entry("Whether the active-set polish was kept.")
    iterations: int = entry("The solver's iterations.", ge=0)
    qp_seconds: float = entry("The QP's time.", unit="s")
    fit_seconds: float = entry("The whole fit's time.", unit="s")
    name: str = entry("The solver.", default="CLARABEL")


@record
class StraightLine(Record):
    """The least-squares line ``output = slope * input + intercept`` on the training window, and its test error."""

    slope: float = entry("The line's slope (output per input).")
    intercept: float = entry("The line's intercept, in the output's unit.")
    test: FitError = entry("Its error on the test window (its fields beside the slope's).", inline=True)


#: why the comparison without creep is a refit, not the creep model with its creep weights zeroed
WITHOUT_CREEP_HOW = ("refit: the same model, operators and windows identified without creep. Zeroing the creep "
                     "weights of the joint fit would also drop the share of the static gain the creep carries, "
                     "scoring a model nobody would use.")


@record(eq=False)
class Refit(Record):
    """A model with creep refitted without it (:data:`WITHOUT_CREEP_HOW`): the model and its errors."""

    model: HysteresisModel = entry("The model refitted without creep.", read=_model_from, write=lambda m: m.to_dict(),
                                   takes="a P-I model without creep")
    fit: FitError = entry("Its error on the training window.")
    test: FitError | None = entry("Its error on the test window.", default=None)

    def __post_init__(self) -> None:
        _check(not isinstance(self.model, CreepPI),
               f"Refit.model must be a model without creep, got '{getattr(self.model, 'kind', '?')}'.")

    def to_dict(self) -> dict[str, Any]:
        """The refit and why it is one (``how``).

        Returns
        -------
        dict
            Its object.
        """
        return {"how": WITHOUT_CREEP_HOW, **super().to_dict()}


@record
class Compensation(Record):
    """The rig driven through the model's inverse in open loop: the force's error against the desired one."""

    rms_N: float = entry("The RMS error.", unit="N", name="compensation_rms_N")
    max_N: float = entry("The largest error.", unit="N", name="compensation_max_N")


# --------------------------------------------------------------------------------------
# the record
# --------------------------------------------------------------------------------------
@record(eq=False)
class IdentifiedModel(Artifact):
    """An identified P-I model and its record (see the module docstring); frozen, checked on construction."""

    KIND: ClassVar[str] = KIND
    NOUN: ClassVar[str] = "the hysteresis model"
    AGAIN: ClassVar[str] = "identify the model again ('piezopreload identify --out')"

    model: HysteresisModel | CreepPI = entry("The identified model.", read=_model_from, write=lambda m: m.to_dict(),
                                             takes="a P-I model")
    data: DataSource = entry("The record it was identified on.", at="inputs")
    units: Units = entry("The model's input and output.")
    output_span: float = entry("``max - min`` of the record's output: what the errors are percentages of.",
                               at="identification")
    output_range: tuple[float, float] = entry("The output's least and largest value over the training window: the "
                                              "range the model was identified over.", at="identification")
    fit: FitError = entry("The error on the training window.", at="identification")
    solver: SolverReport = entry("The QP's report.", at="identification")
    test: FitError | None = entry("The held-out error.", at="identification", default=None)
    line: StraightLine | None = entry("The straight line's errors.", at="identification", name="line_test",
                                      default=None)
    paper_method_test: FitError | None = entry("The paper's method's held-out error.", at="identification",
                                               default=None)
    paper_method_note: str | None = entry("Why the paper's method could not run, where it could not.",
                                          at="identification", default=None)
    without_creep: Refit | None = entry("The refit without creep, for a model with creep.", at="identification",
                                        default=None)
    compensation: Compensation | None = entry("The open-loop compensation check (a study's feedforward).",
                                              at="identification", inline=True, default=None)
    inputs: dict[str, Any] = entry("Hashes of what else it came from (the study, say).", read=object_without("data"),
                                   default={})
    file_sha256: str | None = entry("SHA-256 of the file it was read from or written to.", stored=False,
                                    default=None)

    def __post_init__(self) -> None:
        _check(callable(getattr(self.model, "to_dict", None)) and hasattr(self.model, "kind"),
               f"IdentifiedModel.model must be a P-I model, got {type(self.model).__name__}.")
        _check(math.isfinite(self.output_span) and self.output_span > 0,
               f"IdentifiedModel.output_span must be > 0, got {self.output_span!r}.")
        lo, hi = self.output_range
        _check(math.isfinite(lo) and math.isfinite(hi) and lo <= hi,
               f"IdentifiedModel.output_range must be finite with low <= high, got {self.output_range!r}.")
        object.__setattr__(self, "output_range", (float(lo), float(hi)))

    # ---- the artifact: one reader, one writer ---------------------------------------------------
    @classmethod
    def load(cls, path: str | Path) -> IdentifiedModel:
        """Read a ``hysteresis-model`` artifact: schema and every field checked; errors name the file and field.

        Parameters
        ----------
        path : str or Path
            The file.

        Returns
        -------
        IdentifiedModel
            The record, with the file's SHA-256.
        """
        digest = hashlib.sha256(Path(path).read_bytes()).hexdigest() if Path(path).is_file() else None
        return replace(super().load(path), file_sha256=digest)

    def save(self, path: str | Path) -> IdentifiedModel:
        """Write atomically.

        Parameters
        ----------
        path : str or Path
            The file.

        Returns
        -------
        IdentifiedModel
            The record with the written file's SHA-256.
        """
        self._write(path)
        return replace(self, file_sha256=hashlib.sha256(Path(path).read_bytes()).hexdigest())

    # ---- what it says ---------------------------------------------------------------------------
    def covers(self, low: float, high: float, what: str = "the references") -> None:
        """Refuse outputs ``[low, high]`` the model was not identified over (:func:`require_coverage`).

        Parameters
        ----------
        low, high : float
            The outputs asked for, in the model's output unit.
        what : str
            What asks for them, for the message.

        Raises
        ------
        InputError
            Naming both ranges.
        """
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
