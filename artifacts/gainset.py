"""The gain set: the one type of what ``tune`` writes, ``validate`` judges, ``export`` renders and the rig runs.

A gain set holds the PID gains (SI units, the controller form stated), the feedforward's P-I
model, the plant the gains were tuned and validated on, the references and criteria of that
validation, its verdict (``status``: ``validated`` only if every Monte Carlo requirement of its
study holds, the whole range's and a gain schedule's at each level, else ``candidate``; the
requirements it was judged against, with their margins, are ``requirements`` and the missed ones
``missed``), the tuning's record and the inputs' hashes. It is written and
read through the artifact envelope of :mod:`piezopreload.core.artifacts` (kind ``gain-set``,
content-hashed): :meth:`GainSet.load` is the one reader, :meth:`GainSet.save` the one writer.

The formats controllers read (JSON, LabVIEW, a PLC's Structured Text, a C header, CasADi's C
code) are rendered from a gain set by :func:`piezopreload.rig.export.export`, with every other
export; ``docs/exports.md`` says what each holds.
"""

from __future__ import annotations

import html
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from piezopreload.artifacts.requirements import Requirement, requirements_from_dict, unaccepted
from piezopreload.artifacts.validation import Criteria, ValidationResult
from piezopreload.core.artifacts import content_hash, parse_artifact, read_artifact, write_artifact
from piezopreload.core.errors import ArtifactError, InputError
from piezopreload.models.actuator import Plant
from piezopreload.models.closedloop import Reference
from piezopreload.models.controller import OUTPUT_MAX_V, OUTPUT_MIN_V, SCHEDULE_MAX, Controller, GainSchedule, PIDGains
from piezopreload.models.hysteresis import CreepPI, HysteresisModel, inverse_at, model_from_dict

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["GainSet", "RigInterlocks", "REFERENCES", "STATUSES", "gains_to_dict", "gains_from_dict",
           "schedule_from_dict"]

#: the named references a gain set is validated on (and the rig runs by name)
REFERENCES = ("step", "trajectory")
STATUSES = ("validated", "candidate")

_FORM_SHORT = "ideal/ISA, trapezoidal integral, derivative on measurement, conditional-integration anti-windup"
_REWRITE = "write the gain set again with 'piezopreload tune'"


def gains_to_dict(gains: PIDGains) -> dict[str, Any]:
    """The gains in SI with the controller form stated, plus LabVIEW's minutes; a schedule as its table."""
    out = {"Kc_V_per_N": gains.Kc, "Ti_s": gains.Ti_s, "Td_s": gains.Td_s, "Tf_s": gains.Tf_s, "b": gains.b,
           "u_min_V": gains.u_min_V, "u_max_V": gains.u_max_V, "form": _FORM_SHORT, "labview": gains.labview()}
    if gains.schedule is not None:
        out["schedule"] = gains.schedule.to_dict()
    return out


_SCHEDULE_KEYS = (("levels_N", "levels_N"), ("Kc_V_per_N", "Kc"), ("Ti_s", "Ti_s"), ("Td_s", "Td_s"))
#: the columns a table may leave out (the single value then holds for every entry)
_SCHEDULE_OPTIONAL = (("b", "b"),)


def schedule_from_dict(doc: Any, where: str = "gains.schedule") -> GainSchedule:
    """A gain schedule from its table (``b``, the setpoint weight per entry, optional); an :class:`InputError` names
    the field that is wrong."""
    if not isinstance(doc, dict):
        raise InputError(f"field '{where}' must be an object with {', '.join(k for k, _ in _SCHEDULE_KEYS)}")
    columns: dict[str, tuple[float, ...]] = {}
    for key, name in _SCHEDULE_KEYS + tuple(kn for kn in _SCHEDULE_OPTIONAL if doc.get(kn[0]) is not None):
        column = doc.get(key)
        if not isinstance(column, list):
            raise InputError(f"field '{where}.{key}' must be a list of numbers, got {type(column).__name__}")
        if not 2 <= len(column) <= SCHEDULE_MAX:
            raise InputError(f"field '{where}.{key}' must have 2 to {SCHEDULE_MAX} entries, got {len(column)}")
        try:
            values = tuple(float(x) for x in column)
        except (TypeError, ValueError) as exc:
            raise InputError(f"field '{where}.{key}' must hold numbers: {exc}") from exc
        if not all(np.isfinite(values)):
            raise InputError(f"field '{where}.{key}' must be finite, got {list(column)!r}")
        columns[name] = values
    try:
        return GainSchedule(**columns)
    except ValueError as exc:
        field_name = str(exc).split(" ", 1)[0].removeprefix("schedule.")
        key = {"Kc": "Kc_V_per_N"}.get(field_name, field_name)
        raise InputError(f"field '{where}.{key}' is not valid: {exc}") from exc


def gains_from_dict(g: Any, where: str = "gains") -> PIDGains:
    """The inverse of :func:`gains_to_dict`; an :class:`InputError` names the field (``where``) that is wrong."""
    if not isinstance(g, dict):
        raise InputError(f"field '{where}' must be an object")
    missing = next((k for k in ("Kc_V_per_N", "Ti_s", "Td_s") if k not in g), None)
    if missing:
        raise InputError(f"field '{where}.{missing}' is missing")
    schedule = None if g.get("schedule") is None else schedule_from_dict(g["schedule"], f"{where}.schedule")
    try:
        return PIDGains(Kc=float(g["Kc_V_per_N"]), Ti_s=float(g["Ti_s"]), Td_s=float(g["Td_s"]),
                        Tf_s=float(g.get("Tf_s", 0.0)), b=float(g.get("b", 1.0)),
                        u_min_V=float(g.get("u_min_V", OUTPUT_MIN_V)), u_max_V=float(g.get("u_max_V", OUTPUT_MAX_V)),
                        schedule=schedule)
    except (TypeError, ValueError) as exc:
        raise InputError(f"field '{where}' is not valid: {exc}") from exc


def _requirements_from(doc: dict[str, Any], fail: Any) -> tuple[Requirement, ...]:
    """The requirements the document's status was judged on; a ``validated`` status beside a missed one is refused
    (``fail`` makes the error)."""
    try:
        requirements = requirements_from_dict(doc.get("requirements", []))
    except ArtifactError as exc:
        raise fail(str(exc)) from None
    if doc.get("status") == "validated" and any(not r.met for r in requirements):
        raise fail(f"field 'status' is 'validated' but field 'requirements' holds a missed one; {_REWRITE}")
    return requirements


def _sample_period(doc: dict[str, Any], fail: Any) -> float | None:
    """The document's ``sample_period_s`` (None where it has none); ``fail`` makes the error naming it."""
    x = doc.get("sample_period_s")
    if x is None:
        return None
    if isinstance(x, bool) or not isinstance(x, int | float) or not (np.isfinite(x) and x > 0):
        raise fail(f"field 'sample_period_s' must be a number > 0, got {x!r}")
    return float(x)


@dataclass(frozen=True)
class RigInterlocks:
    """The rig's interlock settings of the gain set's study (its ``[rig_run]``), carried with the gains.

    ``rig run``, ``rig serve``, the OPC UA push and a study's rig stage take these limits unless
    the command line overrides them: the highest force (``force_max_N``), the margin below
    the bolt preload (``force_low_margin_N``), the time of the ramp down (``ramp_s``) and, where
    the study sets one, a stall limit shorter than the plant's (``stall_limit_s``). ``sources``
    says where each came from (the study's key, or how it was derived where the study sets none).
    """

    force_max_N: float
    force_low_margin_N: float
    ramp_s: float
    stall_limit_s: float | None = None
    sources: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("force_max_N", "force_low_margin_N", "ramp_s", "stall_limit_s"):
            value = getattr(self, name)
            if value is None and name == "stall_limit_s":
                continue
            if isinstance(value, bool) or not isinstance(value, int | float) or not (np.isfinite(value) and value > 0):
                raise InputError(f"RigInterlocks.{name} must be a finite number > 0, got {value!r}.")

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"force_max_N": self.force_max_N, "force_low_margin_N": self.force_low_margin_N,
                               "ramp_s": self.ramp_s, "sources": dict(self.sources)}
        if self.stall_limit_s is not None:
            out["stall_limit_s"] = self.stall_limit_s
        return out

    @classmethod
    def from_dict(cls, doc: Any, where: str = "rig_interlocks") -> RigInterlocks:
        """The inverse of :meth:`to_dict`; an :class:`InputError` names the field that is missing or wrong."""
        if not isinstance(doc, dict):
            raise InputError(f"field '{where}' must be an object")
        for key in ("force_max_N", "force_low_margin_N", "ramp_s"):
            if key not in doc:
                raise InputError(f"field '{where}.{key}' is missing")
        sources = doc.get("sources") or {}
        if not isinstance(sources, dict):
            raise InputError(f"field '{where}.sources' must be an object")
        try:
            return cls(doc["force_max_N"], doc["force_low_margin_N"], doc["ramp_s"], doc.get("stall_limit_s"),
                       {str(k): str(v) for k, v in sources.items()})
        except InputError as exc:
            raise InputError(f"field '{where}' is not valid: {exc}") from None


def _plant_from(plant_doc: dict[str, Any], fail: Any) -> Plant | None:
    if plant_doc.get("rig") is None:
        return None
    try:
        return Plant.from_dict(plant_doc["rig"])
    except (KeyError, TypeError, ValueError) as exc:
        raise fail(f"field 'plant.rig' is not a rig: {exc}") from None


def _references_from(refs: Any, fail: Any) -> dict[str, Reference]:
    if not isinstance(refs, dict):
        raise fail("field 'references' must be an object")
    references = {}
    for name, r in refs.items():
        try:
            references[name] = Reference.from_dict(r)
        except ValueError as exc:
            raise fail(f"field 'references.{name}' is not a reference ({exc}); {_REWRITE}") from None
    return references


@dataclass(frozen=True, eq=False)
class GainSet:
    """A gain set (see the module docstring); its dicts are records, read but not changed.

    Parameters
    ----------
    gains : PIDGains
        The PID gains and output range.
    status : str
        ``validated`` (export and the rig accept it) or ``candidate`` (refused unless the user accepts each of
        :attr:`missed` by name).
    feedforward : HysteresisModel, CreepPI or None
        The forward P-I model whose inverse is the feedforward (None: PID alone): classical,
        modified or the paper's asymmetric, with or without creep.
    feedforward_info : dict
        How the feedforward was identified (source, fit).
    plant : Plant or None
        The plant the gains were tuned and validated on; its ``sample_period_s`` is the loop's.
    preset : str or None
        The plant's name (the study's).
    references : dict of Reference
        The references of the validation (``step``, ``trajectory``).
    criteria : Criteria or None
        What the validation requires of every plant.
    validation : ValidationResult or None
        The Monte Carlo validation's result (every plant's metrics, the verdict).
    tuning, inputs : dict
        The tuning's record, the inputs' hashes.
    sample_period_s : float or None
        The controller's sample period where the gain set names no plant (an autotuned loop's); a plant's
        ``sample_period_s`` otherwise.
    rig_interlocks : RigInterlocks or None
        The rig's interlock settings of the study the gains were tuned for (None: a gain set
        written before gain sets carried them; the rig then derives them from the plant).
    content_sha256 : str or None
        The artifact's hash, set by :meth:`load` and :meth:`save`.
    requirements : tuple of Requirement
        The Monte Carlo requirements of its study it was judged against (the whole range's and, for a gain
        schedule, each level's), each with its value and margin: the one record the status, the report and the
        JSON read.
    """

    gains: PIDGains
    status: str = "candidate"
    feedforward: HysteresisModel | CreepPI | None = None
    feedforward_info: dict[str, Any] = field(default_factory=dict)
    plant: Plant | None = None
    preset: str | None = None
    references: dict[str, Reference] = field(default_factory=dict)
    criteria: Criteria | None = None
    validation: ValidationResult | None = None
    tuning: dict[str, Any] | None = None
    inputs: dict[str, Any] = field(default_factory=dict)
    content_sha256: str | None = None
    sample_period_s: float | None = None
    rig_interlocks: RigInterlocks | None = None
    requirements: tuple[Requirement, ...] = ()

    def __post_init__(self) -> None:
        if self.sample_period_s is not None and not (np.isfinite(self.sample_period_s) and self.sample_period_s > 0):
            raise InputError(f"GainSet.sample_period_s must be a finite number > 0, got {self.sample_period_s!r}.")
        if self.rig_interlocks is not None and not isinstance(self.rig_interlocks, RigInterlocks):
            raise InputError(f"GainSet.rig_interlocks must be RigInterlocks, got {type(self.rig_interlocks).__name__}.")
        if self.status not in STATUSES:
            raise InputError(f"GainSet.status must be one of {', '.join(STATUSES)}, got {self.status!r}.")
        bad = [k for k, r in self.references.items() if not isinstance(r, Reference)]
        if bad:
            raise InputError(f"GainSet.references['{bad[0]}'] must be a Reference, "
                             f"got {type(self.references[bad[0]]).__name__}.")
        if not isinstance(self.gains, PIDGains):
            raise InputError(f"GainSet.gains must be PIDGains, got {type(self.gains).__name__}.")

    @property
    def validated(self) -> bool:
        """Whether every Monte Carlo requirement of its study holds (export and the rig need it)."""
        return self.status == "validated"

    @property
    def missed(self) -> tuple[Requirement, ...]:
        """The requirements it was judged against and missed (none for a validated set)."""
        return tuple(r for r in self.requirements if not r.met)

    def require_usable(self, accepted: Iterable[str] = (), *, shown: str = "the gain set",
                       use: str = "used") -> tuple[Requirement, ...]:
        """Refuse a gain set that is not validated unless the user accepts each requirement it missed by name
        (:attr:`Requirement.key`, ``--accept KEY``); returns the missed requirements so accepted (none for a
        validated set), for the caller to record. :class:`InputError` names what was missed and the way to accept
        it, or that the set was never validated (nothing to accept by name then)."""
        if self.validated:
            return ()
        miss = self.missed
        if self.validation is None or not miss:
            why = ("it was never validated" if self.validation is None
                   else f"its validation {self.validation.failed_plants()}")
            raise InputError(f"{shown} is a '{self.status}', not 'validated' ({why}): only validated gains are {use}; "
                             "validate it, or tune it again until it passes ('piezopreload tune')")
        left = unaccepted(miss, accepted)
        if left:
            keys = " ".join(f"--accept {r.key}" for r in left)
            raise InputError(f"{shown} is a '{self.status}': it missed "
                             + "; ".join(r.sentence() for r in left)
                             + f". Only validated gains are {use}; tune again, or accept what it missed by name "
                             f"({keys})")
        return miss

    def verdict(self) -> str:
        """The status in words: what it was validated against, or what it missed by how much."""
        if self.validation is None:
            return f"{self.status}: not validated"
        if self.validated:
            return f"validated: every one of its {len(self.requirements)} Monte Carlo requirements met"
        miss = self.missed
        if not miss:
            return f"{self.status}: {self.validation.failed_plants()}"
        return f"{self.status}: missed " + "; ".join(f"{r.key} ({r.sentence()})" for r in miss)

    # ---- how it shows itself --------------------------------------------------------------------
    def _controller_text(self) -> str:
        g = self.gains
        if g.schedule is not None:
            return f"gain schedule of {g.schedule.size} entries on the setpoint, Kc {min(g.schedule.Kc):.4g}-" \
                   f"{max(g.schedule.Kc):.4g} V/N"
        if g.Td_s == 0.0:
            return f"PI Kc {g.Kc:.4g} V/N, Ti {g.Ti_s:.4g} s"
        return f"PID Kc {g.Kc:.4g} V/N, Ti {g.Ti_s:.4g} s, Td {g.Td_s:.4g} s"

    def __repr__(self) -> str:
        ff = "no feedforward" if self.feedforward is None else f"{self.feedforward.kind} P-I feedforward"
        val = "not validated" if self.validation is None else (
            f"validation {'passed' if self.validation.passed else 'failed'} on {self.validation.n_plants} plants")
        digest = "" if self.content_sha256 is None else f", sha256 {self.content_sha256[:12]}"
        return f"GainSet({self.status}: {self._controller_text()}; {ff}; {val}{digest})"

    def _repr_html_(self) -> str:
        rows = [("status", self.status), ("controller", self._controller_text()),
                ("feedforward", "none" if self.feedforward is None else
                 f"{self.feedforward.kind}, {self.feedforward.n_operators} operators"),
                ("plant", self.preset or "given"), ("content SHA-256", self.content_sha256 or "not saved")]
        body = "".join(f"<tr><td>{k}</td><td>{html.escape(str(v))}</td></tr>" for k, v in rows)
        validation = "" if self.validation is None else self.validation._repr_html_()
        return f"<p><b>Gain set</b></p><table>{body}</table>{validation}"

    def plot(self) -> Figure:
        """The Monte Carlo validation it carries, each bounded metric over the plants against its limit: a Figure."""
        if self.validation is None:
            raise InputError("the gain set carries no validation to plot; validate it first")
        return self.validation.plot()

    # ---- the document ------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The artifact's body (what ``save`` writes inside the envelope)."""
        out: dict[str, Any] = {"status": self.status, "gains": gains_to_dict(self.gains)}
        if self.feedforward is not None or self.feedforward_info:
            out["feedforward"] = {"model": None if self.feedforward is None else self.feedforward.to_dict(),
                                  "units": {"input": "V", "output": "N"}, "identification": self.feedforward_info}
        if self.plant is not None:
            out["plant"] = {"preset": self.preset, "rig": self.plant.to_dict()}
        if self.criteria is not None:
            out["criteria"] = self.criteria.to_dict()
        if self.references:
            out["references"] = {name: ref.to_dict() for name, ref in self.references.items()}
        if self.validation is not None:
            out["validation"] = self.validation.to_dict()
        if self.tuning is not None:
            out["tuning"] = self.tuning
        if self.sample_period_s is not None:
            out["sample_period_s"] = float(self.sample_period_s)
        if self.rig_interlocks is not None:
            out["rig_interlocks"] = self.rig_interlocks.to_dict()
        if self.requirements:
            out["requirements"] = [r.to_dict() for r in self.requirements]
        out["inputs"] = dict(self.inputs)
        return out

    @classmethod
    def from_dict(cls, doc: dict[str, Any], shown: str = "the gain set") -> GainSet:
        """A gain set from its document; :class:`ArtifactError` names ``shown`` and the field."""
        def fail(message: str) -> ArtifactError:
            return ArtifactError(f"{shown}: {message}")

        try:
            gains = gains_from_dict(doc.get("gains"))
        except ValueError as exc:
            raise fail(str(exc)) from None
        status = doc.get("status")
        if status not in STATUSES:
            raise fail(f"field 'status' is {status!r}; expected one of {', '.join(STATUSES)}")
        ff_doc = doc.get("feedforward") or {}
        if not isinstance(ff_doc, dict):
            raise fail("field 'feedforward' must be an object")
        try:
            model = None if ff_doc.get("model") is None else model_from_dict(ff_doc["model"], where="feedforward.model")
        except ValueError as exc:
            raise fail(f"field {exc}") from None
        plant_doc: dict[str, Any] = doc["plant"] if isinstance(doc.get("plant"), dict) else {}
        plant = _plant_from(plant_doc, fail)
        references = _references_from(doc.get("references") or {}, fail)
        for key, value in (("inputs", doc.get("inputs")), ("feedforward.identification", ff_doc.get("identification")),
                           ("tuning", doc.get("tuning"))):
            if value is not None and not isinstance(value, dict):
                raise fail(f"field '{key}' must be an object")
        try:
            criteria = None if doc.get("criteria") is None else Criteria.from_dict(doc["criteria"])
            validation = None if doc.get("validation") is None else ValidationResult.from_dict(doc["validation"])
        except ArtifactError as exc:
            raise fail(f"{exc}; {_REWRITE}") from None
        try:
            interlocks = None if doc.get("rig_interlocks") is None else RigInterlocks.from_dict(doc["rig_interlocks"])
        except InputError as exc:
            raise fail(str(exc)) from None
        requirements = _requirements_from(doc, fail)
        return cls(gains=gains, status=status, feedforward=model,
                   feedforward_info=dict(ff_doc.get("identification") or {}),
                   plant=plant, preset=plant_doc.get("preset"), references=references,
                   criteria=criteria, validation=validation, tuning=doc.get("tuning"),
                   inputs=dict(doc.get("inputs") or {}), content_sha256=doc.get("content_sha256"),
                   sample_period_s=_sample_period(doc, fail), rig_interlocks=interlocks, requirements=requirements)

    # ---- the artifact: one reader, one writer ---------------------------------------------------
    @classmethod
    def load(cls, path: str | Path) -> GainSet:
        """Read a gain-set artifact: schema, fields and content hash checked (a changed file is refused)."""
        return cls.from_dict(read_artifact(path, "gain-set"), str(path))

    @classmethod
    def parse(cls, text: str, shown: str = "the gain set") -> GainSet:
        """:meth:`load` on a document's text (pushed over a network, say)."""
        return cls.from_dict(parse_artifact(text, "gain-set", shown), shown)

    def save(self, path: str | Path) -> GainSet:
        """Write the gain set atomically as a content-hashed artifact; returns it with its hash."""
        doc = write_artifact(path, "gain-set", self.to_dict())
        return replace(self, content_sha256=doc["content_sha256"])

    # ---- what it drives -------------------------------------------------------------------------
    def reference(self, name: str) -> Reference:
        """The named reference of the validation; an error names what the gain set holds."""
        if name not in self.references:
            raise InputError(f"the gain set has no reference '{name}' (it holds "
                             f"{', '.join(self.references) or 'none'}); {_REWRITE}")
        return self.references[name]

    @property
    def plant_sha256(self) -> str | None:
        """The hash that names the plant the gains were tuned and validated on: SHA-256 of its document as canonical
        JSON (None: the gain set names no plant). A served rig takes gain sets of its own plant's hash only."""
        return None if self.plant is None else content_hash(self.plant.to_dict())

    def controller(self) -> Controller:
        """The controller the gain set describes: its gains, the plant's sample period, the feedforward's inverse."""
        if self.plant is not None:
            dt = float(self.plant.sample_period_s)
        elif self.sample_period_s is not None:
            dt = float(self.sample_period_s)
        else:
            raise InputError("field 'plant.rig' is missing: the gain set does not name its plant (the loop's sample "
                             f"period); {_REWRITE}")
        # creep's lags resampled at the loop's period; NotInvertibleError says why a model has no inverse
        inverse = None if self.feedforward is None else inverse_at(self.feedforward, dt)
        return Controller(self.gains, dt, inverse)
