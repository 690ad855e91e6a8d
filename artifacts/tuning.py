"""The tuning record: what the tune stage writes (``tuning.json``, kind ``tuning``) and the
report and validate stage read.

One frozen dataclass per part, each with ``to_dict``/``from_dict``:

* :class:`TuningResult` (``TuningResult``, its former name, is the same class): the tuned gains, the SIMC
  baseline, what the NLP did (:class:`TuningSolve`, what :func:`~piezopreload.tuning.pid.tune_pid` returns), the
  comparison table (:class:`ComparisonRow`, one per gain set with and without the feedforward), the gains on the
  ends of their search range (:class:`ActiveBound`), the minimum-time bound (:class:`MinimumTimeBound`) and the
  tracking floor (:class:`TrackingFloor`), the criteria the table was scored with and the inputs' hashes;
* :meth:`TuningResult.save` writes it through :func:`piezopreload.core.artifacts.write_artifact`,
  :meth:`TuningResult.load` reads it through :func:`~piezopreload.core.artifacts.read_artifact`
  (schema, kind and content hash checked); a missing or non-finite field is named.

The JSON layout is the one the tune stage wrote before the record was typed, with
``active_bounds`` added and the minimum-time bound's ``samples``, ``hold_s`` and ``seconds``.
"""

from __future__ import annotations

import html
import math
from dataclasses import fields, replace
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from piezopreload.artifacts.gainset import GainSet, GainsTable, schedule_from_dict
from piezopreload.core.quantities import number
from piezopreload.core.records import Record, SavedArtifact, entry, hold_members, load_one_of, record
from piezopreload.models.controller import GainSchedule, PIDGains

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["KIND", "ActiveBound", "ComparisonRow", "MinimumTimeBound", "TrackingFloor", "TuningSolve", "TuningResult",
           "SIDES", "warm_start_gains", "GainScheduleRecord", "ScheduleLevel", "SetFigures", "SetGains", "WorstFigures",
           "CHOICES", "LEVEL_FIGURES", "SETS", "ScheduleChoice"]

KIND = "tuning"
SIDES = ("lower", "upper")


def _check_finite(obj: Any, names: tuple[str, ...], optional: tuple[str, ...] = ()) -> None:
    for name in names + optional:
        value = getattr(obj, name)
        if value is None and name in optional:
            continue
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise ValueError(f"{type(obj).__name__}.{name} must be a finite number, got {value!r}")


@record
class ActiveBound(Record):
    """A tuned gain on an end of its search range, and what that means for the controller."""

    gain: str = entry("The gain's field in :class:`~piezopreload.models.controller.PIDGains` (``Kc``, ``Ti_s``, "
                      "``Td_s``, ``Tf_s``).")
    side: str = entry("Which end of the range.", choices=SIDES)
    bound: float = entry("The end of the range, in the gain's unit.")
    note: str = entry('What it means ("the controller is a PI (Td = 0, no derivative filter)").')

    def __post_init__(self) -> None:
        if self.side not in SIDES:
            raise ValueError(f"ActiveBound.side must be one of {', '.join(SIDES)}, got {self.side!r}")
        _check_finite(self, ("bound",))

    def sentence(self) -> str:
        """The bound in words: ``the derivative time Td at its lower bound (1e-05 s): ...``.

        Returns
        -------
        str
            The sentence.
        """
        words, unit = _GAIN_WORDS.get(self.gain, (self.gain, ""))
        return f"{words} at its {self.side} bound ({number(self.bound, '', 4)}{unit}): {self.note}"


#: each gain's words and unit, as a sentence names it
_GAIN_WORDS = {"Kc": ("the gain Kc", " V/N"), "Ti_s": ("the integral time Ti", " s"),
               "Td_s": ("the derivative time Td", " s"), "Tf_s": ("the derivative filter's time Tf", " s"),
               "b": ("the setpoint weight b", "")}


@record
class ComparisonRow(Record):
    """One gain set without or with the feedforward on the nominal rig, scored as the validation scores a plant.

    ``row["settling_s"]`` reads a field by name, as the table's JSON names it.
    """

    gains: str = entry('Which gains ("study", "simc", "tuned").')
    feedforward: bool = entry("Whether the inverse-P-I feedforward ran with them.")
    rise_s: float | None = entry("The step's rise time (None: it never rose).", unit="s")
    settling_s: float | None = entry("The step's settling time (None: it never settled).", unit="s")
    settling_measured_s: float | None = entry("The step's settling time on the measured force.", unit="s")
    overshoot_N: float = entry("The step's overshoot.", unit="N")
    tracking_rms_N: float = entry("The trajectory's RMS error.", unit="N")
    tracking_rms_after_change_N: float = entry("The trajectory's RMS error outside the transport after its changes.",
                                               unit="N")
    peak_command_V: float = entry("The highest command.", unit="V")

    def __post_init__(self) -> None:
        _check_finite(self, ("overshoot_N", "tracking_rms_N", "tracking_rms_after_change_N", "peak_command_V"),
                      ("rise_s", "settling_s", "settling_measured_s"))

    def __getitem__(self, key: str) -> Any:
        if key not in _ROW_FIELDS:
            raise KeyError(key)
        return getattr(self, key)


_ROW_FIELDS = tuple(f.name for f in fields(ComparisonRow))


@record
class MinimumTimeBound(Record):
    """The least settling time any command reaches on the tuning model, beside the tuned loop's."""

    settling_s: float | None = entry("The bound (None: no bound; ``reason`` says why).", unit="s")
    tuned_over_bound_ratio: float | None = entry("The tuned settling over the bound (None where either is missing).")
    samples: int | None = entry("The bound in samples.", ge=0, default=None, omit=True)
    hold_s: float | None = entry("How long the force stays in the band.", unit="s", default=None, omit=True)
    seconds: float | None = entry("What computing it took.", unit="s", default=None, omit=True)
    reason: str | None = entry("Why there is no bound.", default=None, omit=True)

    def __post_init__(self) -> None:
        _check_finite(self, (), ("settling_s", "tuned_over_bound_ratio", "hold_s", "seconds"))
        if self.settling_s is None and not self.reason:
            raise ValueError("MinimumTimeBound without settling_s needs the reason")


@record
class TrackingFloor(Record):
    """The least RMS tracking error of any causal controller without preview, and the tuned loop's over it."""

    rms_N: float = entry("The floor.", unit="N")
    rate_N_per_s: float = entry("The reference's rate it follows from.", unit="N/s")
    tuned_over_floor_ratio: float | None = entry("The tuned loop's RMS error over the floor.")

    def __post_init__(self) -> None:
        _check_finite(self, ("rms_N", "rate_N_per_s"), ("tuned_over_floor_ratio",))


class ScheduleChoice(StrEnum):
    """What a gain schedule's tuning chose: the one robust set, or the schedule (its value is what the record and
    ``tune --json`` write)."""

    ROBUST = "robust"
    SCHEDULE = "schedule"

    @property
    def words(self) -> str:
        """The choice in words, as the console and the report say it."""
        return "the one robust set" if self is ScheduleChoice.ROBUST else "the scheduled gains"

    @property
    def set_key(self) -> str:
        """The chosen set's key in a level's and the whole range's figures (``robust`` or ``scheduled``)."""
        return "robust" if self is ScheduleChoice.ROBUST else "scheduled"


#: what a gain schedule's tuning may choose, in its order
CHOICES = tuple(ScheduleChoice)
#: the worst-case figures a gain schedule's record holds per set and level (the validation's metric names)
LEVEL_FIGURES = ("settling_s", "overshoot_N", "tracking_rms_N", "peak_voltage_V")
#: the two sets a gain schedule's record judges, by their keys in it
SETS = ("robust", "scheduled")


class _EitherSet:
    """What a record holding both sets' figures under ``robust`` and ``scheduled`` reads them by."""

    def of(self, which: str) -> WorstFigures:
        """The figures of one set.

        Parameters
        ----------
        which : str
            ``robust`` or ``scheduled``.

        Returns
        -------
        WorstFigures
            Its worst cases.
        """
        if which not in SETS:
            raise ValueError(f"which must be 'robust' or 'scheduled', got {which!r}")
        figures: WorstFigures = getattr(self, which)
        return figures


@record
class WorstFigures(Record):
    """One set's Monte Carlo worst case of each of :data:`LEVEL_FIGURES` (None: never reached, a settling time) at a
    level or over the whole range, whether it met the criteria and the metrics it failed."""

    settling_s: float | None = entry("The worst settling time (None: never settled).", unit="s")
    overshoot_N: float | None = entry("The worst overshoot.", unit="N")
    tracking_rms_N: float | None = entry("The worst tracking RMS after the changes.", unit="N")
    peak_voltage_V: float | None = entry("The highest command.", unit="V")
    passed: bool = entry("Whether every plant met the criteria.")
    failures: tuple[str, ...] = entry("The metrics it failed.")

    def figure(self, metric: str) -> float | None:
        """The worst case of one of :data:`LEVEL_FIGURES`.

        Parameters
        ----------
        metric : str
            One of :data:`LEVEL_FIGURES`.

        Returns
        -------
        float or None
            Its worst case (None: never reached).
        """
        if metric not in LEVEL_FIGURES:
            raise KeyError(f"{metric!r} is none of the figures {', '.join(LEVEL_FIGURES)}")
        value: float | None = getattr(self, metric)
        return value


@record
class SetGains(Record):
    """A set's gains as a gain schedule's record writes them (an entry's, or the robust set's)."""

    Kc_V_per_N: float = entry("The controller gain.", unit="V/N")
    Ti_s: float = entry("The integral time.", unit="s")
    Td_s: float = entry("The derivative time.", unit="s")
    Tf_s: float = entry("The derivative filter's time constant.", unit="s")
    b: float = entry("The setpoint weight.", absent=1.0)

    @classmethod
    def of(cls, g: PIDGains) -> SetGains:
        """The record of gains ``g``.

        Parameters
        ----------
        g : PIDGains
            The gains.

        Returns
        -------
        SetGains
            Their Kc, Ti, Td, Tf and b.
        """
        return cls(g.Kc, g.Ti_s, g.Td_s, g.Tf_s, g.b)


@record
class SetFigures(_EitherSet, Record):
    """Both sets' worst cases over the whole range (the study's own references)."""

    robust: WorstFigures = entry("The robust set's.")
    scheduled: WorstFigures = entry("The schedule's.")


@record
class ScheduleLevel(_EitherSet, Record):
    """One entry of a gain schedule: its level and window, its gains, its Ms over its window (the robust set's beside
    it), its tuning's record, both sets' Monte Carlo worst cases there and, where the schedule misses the level, what
    stops its entry."""

    level_N: float = entry("The entry's level.", unit="N")
    window_N: tuple[float, float] = entry("The window it was tuned on.", unit="N")
    entry_gains: SetGains = entry("The entry's gains.", name="entry")
    ms: dict[str, float] | None = entry("The maximum sensitivity over the window, per set (None: a record written "
                                        "before it was recorded).", absent=None, omit=True)
    tuning: dict[str, Any] = entry("The entry's tuning: its Ms, the constraints that bind and its objective, or why "
                                   "no gains met the window's specification.")
    robust: WorstFigures = entry("The robust set's worst cases at the level.")
    scheduled: WorstFigures = entry("The schedule's.")
    bound: str | None = entry("What stops the schedule's entry where it misses the level.", default=None, omit=True)


@record
class GainScheduleRecord(Record):
    """A gain schedule's tuning on the preload level (:func:`piezopreload.tuning.schedule.tune_schedule`): the
    choice between the schedule and the one robust set and why, the schedule's table, both sets' gains, each entry's
    level with both sets' Monte Carlo worst cases there, the same over the whole range, and the limits."""

    NOUN: ClassVar[str] = "the gain schedule's record"

    choice: ScheduleChoice = entry("What was chosen.")
    reason: str = entry("Why.")
    levels_N: tuple[float, ...] = entry("The entries' levels.", unit="N")
    table: GainSchedule = entry("The schedule's table.", read=lambda d: schedule_from_dict(d, "table"),
                                write=lambda s: s.to_dict(), takes="a gain schedule's table")
    Tf_s: float = entry("The derivative filter's time constant (the robust set's, held).", unit="s")
    b: float = entry("The robust set's setpoint weight, which the scheduled set carries.")
    robust: SetGains = entry("The one robust set's gains.")
    levels: tuple[ScheduleLevel, ...] = entry("One record per entry.")
    whole_range: SetFigures = entry("Both sets' worst cases over the whole range.")
    plants: int = entry("The Monte Carlo plants per validation.", ge=1)
    figures: tuple[str, ...] = entry("The worst-case figures per set (:data:`LEVEL_FIGURES`).")
    limits: dict[str, float] = entry("The limits the sets were judged against, by figure.")
    seconds: float = entry("The time it took.", unit="s")

    def __post_init__(self) -> None:
        hold_members(self)

    @property
    def chosen_set(self) -> str:
        """The key of the chosen set in :attr:`levels` and :attr:`whole_range` (``robust`` or ``scheduled``)."""
        return self.choice.set_key

    def chosen(self, robust: PIDGains) -> PIDGains:
        """The chosen gains: ``robust`` (the one set the schedule was tuned around), or the same with the schedule.

        Parameters
        ----------
        robust : PIDGains
            The robust set (its output range and filter carried by the schedule).

        Returns
        -------
        PIDGains
            The gains that run.
        """
        return robust if self.choice is ScheduleChoice.ROBUST else replace(robust, schedule=self.table)


@record
class TuningSolve(Record):
    """What the tuning NLP did, the start it came from and how the search ended."""

    status: str = entry("IPOPT's status.")
    iterations: int = entry("IPOPT's iterations.", ge=0)
    seconds: float = entry("The solve's time.", unit="s")
    engine: str = entry("What evaluated the NLP (the compiled simulation, CasADi's graph).")
    compile_s: float = entry("The time spent compiling.", unit="s")
    objective: float = entry("The objective at the optimum.")
    ms: float = entry("The sensitivity peak Ms reached.")
    binding: tuple[str, ...] = entry("The constraints that bind.")
    constraint_margins: dict[str, float] = entry("Every constraint's margin (``g <= 0`` met).")
    fopdt: dict[str, float] = entry("The FOPDT fit the start came from.")
    form: str = entry("The controller's form.", choices=("PI", "PID"), default="PID")
    spec: dict[str, Any] = entry("The tuning's specification.", default={})
    schedule: GainScheduleRecord | None = entry("The gain schedule's record, where one was tuned.", default=None,
                                                omit=True)
    search: str = entry("How the search ended: its runs, those stopped on the iteration limit, where the result "
                        "came from.", default="")
    # what the solve found that the tuning record stores once, at its own top (``gains``, ``simc_baseline``,
    # ``active_bounds``): held where the solver returns it, None in a solve read back from a file
    gains: PIDGains | None = entry("The gains the NLP found (before a gain schedule, where one is tuned, replaces "
                                   "them in the record's ``gains``); None read back.", default=None, stored=False)
    baseline: PIDGains | None = entry("SIMC's gains on the FOPDT fit, the search's start; None read back.",
                                      default=None, stored=False)
    active_bounds: tuple[ActiveBound, ...] = entry("The found gains on an end of their search range; empty read "
                                                   "back.", default=(), stored=False)

    def __post_init__(self) -> None:
        _check_finite(self, ("iterations", "seconds", "compile_s", "objective", "ms"))
        if self.form not in ("PI", "PID"):
            raise ValueError(f"TuningSolve.form must be 'PI' or 'PID', got {self.form!r}")
        object.__setattr__(self, "active_bounds", tuple(self.active_bounds))

    @property
    def stopped_on_limit(self) -> bool:
        """Whether the result came from a run of IPOPT stopped on its iteration limit (its best iterate)."""
        return self.status == "Maximum_Iterations_Exceeded"

    def found(self) -> PIDGains:
        """The gains the NLP found, where this solve is the solver's own result.

        Returns
        -------
        PIDGains
            :attr:`gains`.

        Raises
        ------
        ValueError
            Where the solve was read back from a file (its record's ``gains`` are the tuned ones).
        """
        if self.gains is None:
            raise ValueError("this tuning solve was read back from a file and holds no gains of its own; the "
                             "record's gains (TuningResult.gains) are the tuned ones")
        return self.gains

    def start(self) -> PIDGains:
        """SIMC's gains the search started from, where this solve is the solver's own result.

        Returns
        -------
        PIDGains
            :attr:`baseline`.

        Raises
        ------
        ValueError
            Where the solve was read back from a file (its record's ``simc_baseline`` holds them).
        """
        if self.baseline is None:
            raise ValueError("this tuning solve was read back from a file and holds no baseline of its own; the "
                             "record's simc_baseline holds it")
        return self.baseline


@record
class TuningResult(SavedArtifact):
    """Tuned PID gains around a study's compensated rig, compared and bounded: the tune step's result and the tune
    stage's artifact (``tuning.json``), one type.

    The study's ``[controller]``, SIMC's and the tuned gains on the nominal plant, PID alone and with the
    feedforward (``table``), the gains on the ends of their search range (``active_bounds``), the least settling
    time any command reaches (``minimum_time``, the tuned over it ``tuned_over_bound_ratio``) and the trajectory's
    least RMS error any causal controller reaches (``tracking_floor``). The study validates it
    (:meth:`Study.validate <piezopreload.study.Study.validate>`).
    """

    KIND: ClassVar[str] = KIND
    NOUN: ClassVar[str] = "the tuning record"
    AGAIN: ClassVar[str] = "run the tune stage again"

    gains: PIDGains = entry("The tuned gains (the gain schedule's when one was chosen).", via=GainsTable)
    simc_baseline: PIDGains = entry("SIMC's gains on the FOPDT fit.", via=GainsTable)
    solve: TuningSolve = entry("What the NLP did.", name="tuning")
    table: tuple[ComparisonRow, ...] = entry("Each gain set without and with the feedforward on the nominal rig.")
    minimum_time: MinimumTimeBound = entry("The minimum-time bound the tuned settling is read against.")
    tracking_floor: TrackingFloor = entry("The tracking floor the tuned RMS error is read against.")
    active_bounds: tuple[ActiveBound, ...] = entry("The tuned gains on an end of their search range.", default=())
    criteria: dict[str, Any] = entry("How the table was scored.", default={}, required=True)
    tracking_improvement: dict[str, float | None] = entry("The study's starting gains' tracking RMS over the tuned "
                                                          "one.", default={})
    inputs: dict[str, Any] = entry("The inputs' hashes.", default={}, required=True)
    published: dict[str, Any] | None = entry("The published figures the table is read beside, where the study "
                                             "declares them (``[published]``).", default=None, omit=True)

    def __post_init__(self) -> None:
        for name in ("gains", "simc_baseline"):
            if not isinstance(getattr(self, name), PIDGains):
                raise ValueError(f"TuningResult.{name} must be PIDGains, got {type(getattr(self, name)).__name__}")
        object.__setattr__(self, "table", tuple(self.table))
        object.__setattr__(self, "active_bounds", tuple(self.active_bounds))

    def row(self, gains: str = "tuned", feedforward: bool = True) -> ComparisonRow:
        """One row of the comparison table.

        Parameters
        ----------
        gains : str
            Which gains ("study", "simc", "tuned").
        feedforward : bool
            With the feedforward or without.

        Returns
        -------
        ComparisonRow
            The row.

        Raises
        ------
        KeyError
            Naming what the table holds, where it holds no such row.
        """
        for r in self.table:
            if r.gains == gains and r.feedforward == feedforward:
                return r
        raise KeyError(f"no row ({gains!r}, feedforward={feedforward}) in the table; it holds "
                       + ", ".join(f"({r.gains!r}, {r.feedforward})" for r in self.table))

    def __repr__(self) -> str:
        g, m, s = self.gains, self.minimum_time, self.solve
        bound = "none" if m.settling_s is None else f"{m.settling_s:.4g} s"
        study = f"{self.inputs['study']}: " if self.inputs.get("study") else ""
        try:
            settling = _fmt(self.row().settling_s)
        except KeyError:  # a record without the comparison
            settling = "not compared"
        return (f"TuningResult({study}{s.form} Kc {g.Kc:.4g} V/N, Ti {g.Ti_s:.4g} s, Td {g.Td_s:.4g} s, "
                f"Tf {g.Tf_s:.4g} s, b {g.b:.3g}; Ms {s.ms:.3g}; tuned settling {settling} s, minimum-time bound "
                f"{bound}; {len(self.active_bounds)} gain(s) on a bound)")

    def _repr_html_(self) -> str:
        head = "".join(f"<th>{h}</th>" for h in ("gains", "feedforward", "settling (s)", "overshoot (N)",
                                                 "tracking RMS (N)", "peak command (V)"))
        rows = "".join(f"<tr><td>{r.gains}</td><td>{'yes' if r.feedforward else 'no'}</td>"
                       f"<td>{_fmt(r.settling_s)}</td><td>{r.overshoot_N:.3g}</td><td>{r.tracking_rms_N:.3g}</td>"
                       f"<td>{r.peak_command_V:.3g}</td></tr>" for r in self.table)
        bounds = "".join(f"<li>{html.escape(b.sentence())}</li>" for b in self.active_bounds)
        return (f"<p><b>Tuned {self.solve.form}</b>: <code>{html.escape(repr(self))}</code></p>"
                f"<table><tr>{head}</tr>{rows}</table>"
                + (f"<p>Gains on a bound:</p><ul>{bounds}</ul>" if bounds else ""))

    def plot(self) -> Figure:
        """The comparison table as bars: the settling time and the tracking RMS of each gain set, PID alone and with
        the feedforward (log scale).

        Returns
        -------
        Figure
            A matplotlib Figure (no pyplot state).
        """
        from matplotlib.figure import Figure

        fig = Figure(figsize=(7.0, 2.6))
        axes = fig.subplots(1, 2)
        labels = [f"{r.gains}{' + FF' if r.feedforward else ''}" for r in self.table]
        colours = ["tab:blue" if r.feedforward else "tab:gray" for r in self.table]
        settling = [math.nan if r.settling_s is None else r.settling_s for r in self.table]
        for ax, values, label in ((axes[0], settling, "settling time (s)"),
                                  (axes[1], [r.tracking_rms_N for r in self.table], "tracking RMS (N)")):
            ax.bar(range(len(labels)), values, color=colours)
            ax.set_xticks(range(len(labels)), labels, rotation=30, ha="right")
            ax.set_ylabel(label)
            ax.set_yscale("log")
        fig.tight_layout()
        return fig



def _fmt(x: float | None) -> str:
    return "none" if x is None else f"{x:.4g}"


def warm_start_gains(path: str | Path) -> PIDGains:
    """The gains of a tuning record (``tuning.json``) or of a gain set (``gains.json``): what ``[tuning] warm_start``
    names.

    Parameters
    ----------
    path : str or Path
        The file, read through its kind's one reader (schema, fields and content hash checked).

    Returns
    -------
    PIDGains
        Its gains.

    Raises
    ------
    ArtifactError
        Naming the file where it is neither.
    """
    return load_one_of(path, TuningResult, GainSet).gains
