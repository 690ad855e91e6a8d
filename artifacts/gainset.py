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
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from piezopreload.artifacts.requirements import Requirement, unaccepted
from piezopreload.artifacts.validation import Criteria, ValidationResult
from piezopreload.core.artifacts import content_hash, parse_artifact
from piezopreload.core.errors import InputError
from piezopreload.core.records import Artifact, Raw, Record, entry, kind_of, record
from piezopreload.models.actuator import Plant
from piezopreload.models.closedloop import Reference
from piezopreload.models.controller import OUTPUT_MAX_V, OUTPUT_MIN_V, SCHEDULE_MAX, Controller, GainSchedule, PIDGains
from piezopreload.models.hysteresis import CreepPI, HysteresisModel, inverse_at, model_from_dict

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["GainSet", "GainsTable", "RigInterlocks", "REFERENCES", "STATUSES", "gains_from_dict",
           "schedule_from_dict"]

#: the named references a gain set is validated on (and the rig runs by name)
REFERENCES = ("step", "trajectory")
STATUSES = ("validated", "candidate")

_FORM_SHORT = "ideal/ISA, trapezoidal integral, derivative on measurement, conditional-integration anti-windup"
_FORM_SHORT_2 = ("ideal/ISA on the measurement through a second-order filter (Tustin), trapezoidal integral, "
                 "derivative on the filtered measurement, conditional-integration anti-windup")
_REWRITE = "write the gain set again with 'piezopreload tune'"


@record
class _ScheduleTable(Record):
    """A gain schedule as a gain set holds it: one column per gain, one entry per setpoint level."""

    NOUN: ClassVar[str] = "the gain schedule"

    levels_N: tuple[float, ...] = entry("The setpoints of the entries.", unit="N", size=(2, SCHEDULE_MAX),
                                        increasing=True)
    Kc_V_per_N: tuple[float, ...] = entry("The controller gain per entry.", unit="V/N", size="levels_N")
    Ti_s: tuple[float, ...] = entry("The integral time per entry.", unit="s", gt=0, size="levels_N")
    Td_s: tuple[float, ...] = entry("The derivative time per entry.", unit="s", ge=0, size="levels_N")
    b: tuple[float, ...] | None = entry("The setpoint weight per entry (None: the gains' single one).",
                                        size="levels_N", default=None, omit=True)

    @classmethod
    def from_value(cls, s: GainSchedule) -> _ScheduleTable:
        return cls(s.levels_N, s.Kc, s.Ti_s, s.Td_s, s.b)

    def to_value(self) -> GainSchedule:
        return GainSchedule(self.levels_N, self.Kc_V_per_N, self.Ti_s, self.Td_s, self.b)


@record
class GainsTable(Record):
    """The gains as an artifact holds them: SI, the controller form stated, LabVIEW's minutes beside them.

    The document's form of :class:`~piezopreload.models.controller.PIDGains` (a field declared with
    ``via=GainsTable`` is read and written through it).
    """

    NOUN: ClassVar[str] = "the gains"

    Kc_V_per_N: float = entry("The controller gain.", unit="V/N")
    Ti_s: float = entry("The integral time.", unit="s")
    Td_s: float = entry("The derivative time.", unit="s")
    Tf_s: float = entry("The derivative filter's time constant.", unit="s", default=0.0)
    b: float = entry("The setpoint weight of the proportional action.", default=1.0)
    u_min_V: float = entry("The output range's low end.", unit="V", default=OUTPUT_MIN_V)
    u_max_V: float = entry("The output range's high end.", unit="V", default=OUTPUT_MAX_V)
    schedule: GainSchedule | None = entry("The gains scheduled on the setpoint (None: one set of gains).",
                                          via=_ScheduleTable, default=None, omit=True)
    filter_order: int | None = entry("The filter's order: 2, the measurement through ``1/(1 + Tf s + (Tf s)^2/2)`` "
                                     "(Tustin's rule); absent (None), the first-order filter ``1/(Tf s + 1)`` on the "
                                     "derivative, as every gain set written before the second order was.",
                                     default=None, omit=True, ge=2, le=2)

    @classmethod
    def from_value(cls, g: PIDGains) -> GainsTable:
        """The table of gains ``g``.

        Parameters
        ----------
        g : PIDGains
            The gains.

        Returns
        -------
        GainsTable
            Their table.
        """
        return cls(g.Kc, g.Ti_s, g.Td_s, g.Tf_s, g.b, g.u_min_V, g.u_max_V, g.schedule,
                   None if g.filter_order == 1 else g.filter_order)

    def to_value(self) -> PIDGains:
        """The gains the table holds.

        Returns
        -------
        PIDGains
            The gains, checked by their own rules.
        """
        return PIDGains(Kc=self.Kc_V_per_N, Ti_s=self.Ti_s, Td_s=self.Td_s, Tf_s=self.Tf_s, b=self.b,
                        u_min_V=self.u_min_V, u_max_V=self.u_max_V, schedule=self.schedule,
                        filter_order=1 if self.filter_order is None else self.filter_order)

    def to_dict(self) -> dict[str, Any]:
        """The table, the controller form in words and LabVIEW's units beside it.

        Returns
        -------
        dict
            The gains' object.
        """
        form = _FORM_SHORT if self.filter_order is None else _FORM_SHORT_2
        return {**super().to_dict(), "form": form, "labview": self.to_value().labview()}


def gains_from_dict(g: Any, where: str = "gains") -> PIDGains:
    """The gains of their object as a gain set holds them (``GainsTable.from_value(gains).to_dict()`` writes it).

    Parameters
    ----------
    g : dict
        The gains' object.
    where : str
        Its path in its document, for the messages.

    Returns
    -------
    PIDGains
        The gains.

    Raises
    ------
    ArtifactError
        Naming the field (``gains.Ti_s``) that is missing or wrong.
    """
    return GainsTable.from_dict(g, path=where).to_value()


def schedule_from_dict(doc: Any, where: str = "gains.schedule") -> GainSchedule:
    """A gain schedule from its table (``b``, the setpoint weight per entry, optional).

    Parameters
    ----------
    doc : dict
        The table: ``levels_N``, ``Kc_V_per_N``, ``Ti_s``, ``Td_s`` and, optionally, ``b``.
    where : str
        Its path in its document, for the messages.

    Returns
    -------
    GainSchedule
        The schedule.

    Raises
    ------
    ArtifactError
        Naming the field (``gains.schedule.Ti_s``) that is missing or wrong.
    """
    return _ScheduleTable.from_dict(doc, path=where).to_value()


@record
class RigInterlocks(Record):
    """The rig's interlock settings of the gain set's study (its ``[rig_run]``), carried with the gains.

    ``rig run``, ``rig serve``, the OPC UA push and a study's rig stage take these limits unless
    the command line overrides them.
    """

    NOUN: ClassVar[str] = "the rig's interlocks"

    force_max_N: float = entry("The highest force.", unit="N", gt=0)
    force_low_margin_N: float = entry("The margin below the bolts' preload the force may fall to.", unit="N", gt=0)
    ramp_s: float = entry("The time of the ramp down.", unit="s", gt=0)
    stall_limit_s: float | None = entry("Where the study sets one, a stall limit shorter than the plant's.",
                                        unit="s", gt=0, default=None, omit=True)
    sources: dict[str, str] = entry("Where each came from (the study's key, or how it was derived where the study "
                                    "sets none).", default={})

    def __post_init__(self) -> None:
        for name in ("force_max_N", "force_low_margin_N", "ramp_s", "stall_limit_s"):
            value = getattr(self, name)
            if value is None and name == "stall_limit_s":
                continue
            if isinstance(value, bool) or not isinstance(value, int | float) or not (np.isfinite(value) and value > 0):
                raise InputError(f"RigInterlocks.{name} must be a finite number > 0, got {value!r}.")


def _model_from(doc: Any) -> HysteresisModel | CreepPI:
    return model_from_dict(doc, where="feedforward.model")


@record(eq=False)
class GainSet(Artifact):
    """A gain set (see the module docstring); its dicts are records, read but not changed."""

    KIND: ClassVar[str] = "gain-set"
    NOUN: ClassVar[str] = "the gain set"
    AGAIN: ClassVar[str] = _REWRITE
    HASHED: ClassVar[bool] = True

    gains: PIDGains = entry("The PID gains and output range.", via=GainsTable)
    status: str = entry("``validated`` (export and the rig accept it) or ``candidate`` (refused unless the user "
                        "accepts each of :attr:`missed` by name).", choices=STATUSES, default="candidate",
                        required=True)
    feedforward: HysteresisModel | CreepPI | None = entry(
        "The forward P-I model whose inverse is the feedforward (None: PID alone): classical, modified or the "
        "paper's asymmetric, with or without creep.", at="feedforward", name="model", read=_model_from,
        write=lambda m: m.to_dict(), takes="a P-I model", default=None)
    feedforward_info: dict[str, Any] = entry("How the feedforward was identified (source, fit).", at="feedforward",
                                             name="identification", default={})
    plant: Plant | None = entry("The plant the gains were tuned and validated on; its ``sample_period_s`` is the "
                                "loop's.", at="plant", name="rig", read=Plant.from_dict, write=Plant.to_dict,
                                takes="a rig's parameters", default=None)
    preset: str | None = entry("The plant's name (the study's).", at="plant", default=None)
    references: dict[str, Reference] = entry("The references of the validation (``step``, ``trajectory``).",
                                             read=Reference.from_dict, write=Reference.to_dict, each=True,
                                             takes="references", default={}, omit=True)
    criteria: Criteria | None = entry("What the validation requires of every plant.", default=None, omit=True)
    validation: ValidationResult | None = entry("The Monte Carlo validation's result (every plant's metrics, the "
                                                "verdict).", default=None, omit=True)
    tuning: dict[str, Any] | None = entry("The tuning's record.", default=None, omit=True)
    inputs: dict[str, Any] = entry("The inputs' hashes.", default={}, required=True)
    content_sha256: str | None = entry("The artifact's hash, set by :meth:`load` and :meth:`save`.", default=None)
    sample_period_s: float | None = entry("The controller's sample period where the gain set names no plant (an "
                                          "autotuned loop's); a plant's ``sample_period_s`` otherwise.", unit="s",
                                          gt=0, default=None, omit=True)
    rig_interlocks: RigInterlocks | None = entry(
        "The rig's interlock settings of the study the gains were tuned for (None: a gain set written before gain "
        "sets carried them; the rig then derives them from the plant).", default=None, omit=True)
    requirements: tuple[Requirement, ...] = entry(
        "The Monte Carlo requirements of its study it was judged against (the whole range's and, for a gain schedule, "
        "each level's), each with its value and margin: the one record the status, the report and the JSON read.",
        default=(), omit=True)

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
        it, or that the set was never validated (nothing to accept by name then).

        Parameters
        ----------
        accepted : iterable of str
            The keys (:attr:`Requirement.key`) of the missed requirements the user accepts by name (``--accept KEY``).
        shown : str
            What the error message calls the gain set (its file, or "the gain set").
        use : str
            What the gains are about to be ("used", "pushed"), for the message.

        Returns
        -------
        tuple of Requirement
            The missed requirements the user accepted, each with its value and margin; empty for a validated set.

        Raises
        ------
        InputError
            Where the set was never validated, or missed a requirement that ``accepted`` does not name.
        """
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
        """The status in words: what it was validated against, or what it missed by how much.

        Returns
        -------
        str
            ``validated: ...`` with the number of requirements met, ``<status>: not validated``, or the status and each
            missed requirement's key and sentence (achieved, limit, margin).
        """
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
        second = f", second-order filter Tf {g.Tf_s:.4g} s" if g.filter_order == 2 else ""
        if g.Td_s == 0.0:
            return f"PI Kc {g.Kc:.4g} V/N, Ti {g.Ti_s:.4g} s{second}"
        return f"PID Kc {g.Kc:.4g} V/N, Ti {g.Ti_s:.4g} s, Td {g.Td_s:.4g} s{second}"

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
        """The Monte Carlo validation it carries, each bounded metric over the plants against its limit: a Figure.

        Returns
        -------
        matplotlib.figure.Figure
            One histogram per bounded metric over the Monte Carlo plants, its limit dashed.

        Raises
        ------
        InputError
            Where the gain set carries no validation.
        """
        if self.validation is None:
            raise InputError("the gain set carries no validation to plot; validate it first")
        return self.validation.plot()

    # ---- the document ------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The artifact's body (what :meth:`save` writes inside the envelope).

        Returns
        -------
        dict
            The document without its envelope and hash.
        """
        out = super().to_dict()
        del out["content_sha256"]
        if self.feedforward is None and not self.feedforward_info:
            del out["feedforward"]
        else:
            out["feedforward"]["units"] = {"input": "V", "output": "N"}
        if self.plant is None:
            del out["plant"]
        return out

    def _check_document(self, raw: Raw) -> None:
        if self.validated and self.missed:
            raise raw.fail("status", "is 'validated' but field 'requirements' holds a missed one")

    # ---- the artifact: one reader, one writer ---------------------------------------------------
    @classmethod
    def parse(cls, text: str, shown: str = "the gain set") -> GainSet:
        """:meth:`load` on a document's text (pushed over a network, say).

        Parameters
        ----------
        text : str
            The document's text.
        shown : str
            What the messages call it.

        Returns
        -------
        GainSet
            The gain set, its hash checked.
        """
        return cls.from_dict(parse_artifact(text, kind_of(cls), shown, fields=False), shown)

    def save(self, path: str | Path) -> GainSet:
        """Write the gain set atomically as a content-hashed artifact.

        Parameters
        ----------
        path : str or Path
            The file.

        Returns
        -------
        GainSet
            The gain set with the hash it was written with.
        """
        doc = self._write(path)
        return replace(self, content_sha256=doc["content_sha256"])

    # ---- what it drives -------------------------------------------------------------------------
    def reference(self, name: str) -> Reference:
        """The named reference of the validation; an error names what the gain set holds.

        Parameters
        ----------
        name : str
            The reference's name among :attr:`references` (``step``, ``trajectory``).

        Returns
        -------
        Reference
            The reference the gains were validated on.

        Raises
        ------
        InputError
            Where the gain set holds no reference of that name; the message lists those it holds.
        """
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
        """The controller the gain set describes: its gains, the plant's sample period, the feedforward's inverse.

        Returns
        -------
        Controller
            The discrete controller of :attr:`gains` at the plant's sample period (or the gain set's own
            :attr:`sample_period_s`), with the feedforward's inverse resampled at that period (None without a
            feedforward).

        Raises
        ------
        InputError
            Where the gain set names neither a plant nor a sample period.
        """
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
