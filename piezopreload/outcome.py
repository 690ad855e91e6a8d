"""What a whole study returns: :class:`StudyResult` (``study.run()``, ``piezopreload run``, ``report``).

It holds where the outputs went, what each stage did, the study's headline figures
(:class:`Headline`, what ``run --json`` prints under ``summary``) and every requirement the
stages checked with its verdict; ``exit_code`` is 0 when every requirement is met and
:data:`~piezopreload.artifacts.requirements.EXIT_REQUIREMENT_MISSED` when one is missed.
"""

from __future__ import annotations

import html
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from piezopreload.artifacts.manifest import StudyRef, StudyRunManifest
from piezopreload.artifacts.requirements import EXIT_REQUIREMENT_MISSED, Requirement, least_margin, missed
from piezopreload.artifacts.sensitivity import SensitivityRecord
from piezopreload.artifacts.summaries import RigSummary, SystemSummary, ValidateSummary
from piezopreload.artifacts.thermal import ThermalSummary
from piezopreload.core.quantities import number
from piezopreload.core.stages import StageOutcome

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["StageOutcome", "Headline", "RunSummary", "StudyResult"]


@dataclass(frozen=True)
class Headline:
    """The study's headline figures: the whole system's (None where the study has no system stage; the rigidity
    in the machine beside its table-comparable figure and the axis stiffness at the table, the nut axial deflection
    beside the axis deflection at the table, the lift-off margin against the schedule's bound (the design's own
    constraint where that row binds the schedule: the requirement's ``basis`` says) beside the physical one by the nut
    law over the Monte Carlo plants: None where the run has no margin basis; ``thermal``
    where it has a ``[thermal]`` table: ``heat_mean_W``, ``temperature_rise_max_K``, ``growth_max_um``,
    ``positioning_error_max_um``, ... each ``{"schedule": ..., "constant": ...}`` in the document: a
    :class:`~piezopreload.artifacts.thermal.ThermalSummary`), the gain set's status and
    the rig run's tracking; ``sensitivity`` the verdicts under the modelling assumptions' ranges (in the document
    its rows, and ``verdict_robust`` beside them)."""

    tracking_rms_pct_of_range: float | None = None
    tracking_rms_pct_of_range_before_learning: float | None = None
    tracking_rms_N: float | None = None
    tracking_rms_N_before_learning: float | None = None
    learning_iterations: int | None = None
    learning_trials: int | None = None
    tracking_max_N: float | None = None
    rigidity_min_cutting_N_per_um: float | None = None
    rigidity_required_at_min_N_per_um: float | None = None
    rigidity_ratio_min: float | None = None
    rigidity_at_worst_ratio_N_per_um: float | None = None
    rigidity_required_at_worst_ratio_N_per_um: float | None = None
    rigidity_in_machine_N_per_um: float | None = None
    rigidity_table_N_per_um: float | None = None
    rigidity_in_machine_factor: float | None = None
    axis_stiffness_at_table_min_N_per_um: float | None = None
    axis_stiffness_at_table_max_N_per_um: float | None = None
    nut_axial_deflection_max_um: float | None = None
    axis_deflection_at_table_max_um: float | None = None
    lift_off_margin_pct: float | None = None
    lift_off_margin_physical_pct: float | None = None
    lift_off_margin_physical_nominal_pct: float | None = None
    lift_off_margin_catalogue_pct: float | None = None
    lift_off_plants: int | None = None
    friction_energy_per_cycle: float | None = None
    friction_saved_fraction: float | None = None
    preload_margin_N: float | None = None
    thermal: ThermalSummary | None = None  # the shift's figures, each for the schedule and the constant preload
    sensitivity: SensitivityRecord | None = None  # the verdicts under the modelling assumptions' ranges
    system: str = "not run"
    gain_set_status: str | None = None
    rig_tracking_rms_N: float | None = None

    @classmethod
    def from_manifest(cls, manifest: StudyRunManifest) -> Headline:
        """The headline from the stages' records of a run's ``pipeline.json``."""
        system, validate, rig = (manifest.summary(SystemSummary), manifest.summary(ValidateSummary),
                                 manifest.summary(RigSummary))
        head = cls(system=manifest.status("system") or "not run",
                   gain_set_status=None if validate is None else validate.status,
                   rig_tracking_rms_N=None if rig is None else rig.tracking_rms_N)
        if system is None:
            return head
        n, before = system.numbers, system.before
        head = replace(
            head, tracking_rms_pct_of_range=n.tracking_rms_pct_of_range, tracking_rms_N=n.tracking_rms_N,
            tracking_max_N=n.tracking_max_N, rigidity_min_cutting_N_per_um=n.rigidity_min_cutting_N_per_um,
            rigidity_required_at_min_N_per_um=n.rigidity_required_at_min_N_per_um,
            rigidity_ratio_min=n.rigidity_ratio_min,
            rigidity_at_worst_ratio_N_per_um=n.rigidity_at_worst_ratio_N_per_um,
            rigidity_required_at_worst_ratio_N_per_um=n.rigidity_required_at_worst_ratio_N_per_um,
            nut_axial_deflection_max_um=n.deflection_max_um, friction_energy_per_cycle=n.friction_energy_per_cycle,
            friction_saved_fraction=n.friction_saved_fraction, preload_margin_N=system.preload_margin_N,
            thermal=system.thermal, sensitivity=system.sensitivity,
            lift_off_margin_pct=next((r.margin_pct for r in system.requirements if r.key == "schedule.lift_off_margin"),
                                     None))
        b = system.basis
        if b is not None:
            head = replace(
                head, rigidity_in_machine_N_per_um=b.rigidity_in_machine_N_per_um,
                rigidity_table_N_per_um=b.rigidity_table_N_per_um,
                rigidity_in_machine_factor=b.rigidity_in_machine_factor,
                axis_stiffness_at_table_min_N_per_um=b.axis_stiffness_min_N_per_um,
                axis_stiffness_at_table_max_N_per_um=b.axis_stiffness_max_N_per_um,
                axis_deflection_at_table_max_um=b.axis_deflection_max_um,
                lift_off_margin_physical_pct=b.lift_off_margin_physical_pct,
                lift_off_margin_physical_nominal_pct=b.lift_off_margin_physical_nominal_pct,
                lift_off_margin_catalogue_pct=b.lift_off_margin_catalogue_pct, lift_off_plants=b.lift_off_plants)
        if before is None:
            return head
        return replace(head, tracking_rms_pct_of_range_before_learning=before.tracking_rms_pct_of_range_before_learning,
                       tracking_rms_N_before_learning=before.tracking_rms_N_before_learning,
                       learning_iterations=before.learning_iterations, learning_trials=before.learning_trials)

    @property
    def verdict_robust(self) -> bool | None:
        """Whether every verdict holds over every assumption's range (None: no sensitivity study ran)."""
        return None if self.sensitivity is None else self.sensitivity.verdict_robust

    def to_dict(self) -> dict[str, Any]:
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        out["thermal"] = None if self.thermal is None else self.thermal.to_dict()
        out["sensitivity"] = None if self.sensitivity is None else [r.to_dict() for r in self.sensitivity.rows]
        out["verdict_robust"] = self.verdict_robust
        return out


@dataclass(frozen=True)
class RunSummary:
    """A run's headline figures and every requirement its stages checked: ``run --json``'s ``summary``.

    Parameters
    ----------
    headline : Headline
        The run's headline figures.
    requirements : tuple of Requirement
        Every requirement the stages checked, in stage order, each with its verdict.
    """

    headline: Headline
    requirements: tuple[Requirement, ...]

    @property
    def missed(self) -> tuple[Requirement, ...]:
        """The requirements missed, in stage order."""
        return missed(self.requirements)

    @property
    def requirements_met(self) -> bool | None:
        """Whether every requirement the stages checked is met (None: the study checked none)."""
        return None if not self.requirements else not self.missed

    @property
    def least_margin(self) -> Requirement | None:
        """The requirement nearest to being missed (the least margin as a share of its limit), or None."""
        return least_margin(self.requirements)

    def to_dict(self) -> dict[str, Any]:
        """The headline figures, whether every requirement is met (None: none checked), the missed ones and every
        one, each with its margin.

        Returns
        -------
        dict
            The headline's figures by name, ``requirements_met`` (True, False, or None where none was checked), and
            ``requirements_missed`` and ``requirements``, each requirement as its record's document.
        """
        return {**self.headline.to_dict(), "requirements_met": self.requirements_met,
                "requirements_missed": [r.to_dict() for r in self.missed],
                "requirements": [r.to_dict() for r in self.requirements]}


@dataclass(frozen=True)
class StudyResult:
    """A study's run: its outputs, its stages, its headline figures and its requirements' verdicts.

    ``to_dict()`` is what ``piezopreload run --json`` prints; ``exit_code`` what it exits with.

    Parameters
    ----------
    out : Path
        The run's folder.
    study : dict of str to str
        The study's ``path``, ``sha256`` and ``name`` (and its ``copy`` in the run's folder).
    stages : tuple of StageOutcome
        Each stage's outcome, in order (ran, up to date, or did not apply, with why).
    seconds : float
        The wall-clock time the run took (s).
    headline : Headline
        The run's headline figures.
    requirements : tuple of Requirement
        Every requirement the stages checked, with its value and margin, in stage order.
    report : Path or None
        The PDF report (None: not written).
    gain_set : Path or None
        The gain set the run wrote (None: none).
    gain_set_sha256 : str or None
        Its content hash.
    rig_log : Path or None
        The rig run's log (None: the rig stage did not run).
    """

    out: Path
    study: StudyRef
    stages: tuple[StageOutcome, ...]
    seconds: float
    headline: Headline
    requirements: tuple[Requirement, ...]
    report: Path | None = None
    gain_set: Path | None = None
    gain_set_sha256: str | None = None
    rig_log: Path | None = None

    @property
    def ran(self) -> tuple[str, ...]:
        """The stages that ran (the others were up to date or did not apply)."""
        return tuple(s.stage for s in self.stages if s.ran)

    @property
    def summary(self) -> RunSummary:
        """The headline figures and the verdicts (``to_dict()["summary"]``)."""
        return RunSummary(self.headline, self.requirements)

    @property
    def missed(self) -> tuple[Requirement, ...]:
        """The requirements missed, in stage order."""
        return self.summary.missed

    @property
    def requirements_met(self) -> bool | None:
        """Whether every requirement the stages checked is met (None: the study checked none)."""
        return self.summary.requirements_met

    @property
    def exit_code(self) -> int:
        """The run's exit status: ``EXIT_REQUIREMENT_MISSED`` where a requirement was missed, else 0."""
        return EXIT_REQUIREMENT_MISSED if self.requirements_met is False else 0

    def to_dict(self) -> dict[str, Any]:
        """What ``run --json`` prints: the outputs, the stages, ``summary`` (the headline and the verdicts).

        Returns
        -------
        dict
            ``out``, ``study``, ``stages``, ``ran``, ``seconds``, the written files' paths (``report``, ``gain_set``,
            ``rig_log``; None where not written), ``gain_set_sha256``, ``summary`` (:meth:`RunSummary.to_dict`) and
            ``exit_code``.
        """
        def path(p: Path | None) -> str | None:
            return None if p is None else str(p)

        return {"out": str(self.out), "study": self.study.to_dict(), "stages": [s.to_dict() for s in self.stages],
                "ran": list(self.ran), "seconds": self.seconds, "report": path(self.report),
                "gain_set": path(self.gain_set), "gain_set_sha256": self.gain_set_sha256, "rig_log": path(self.rig_log),
                "summary": self.summary.to_dict(), "exit_code": self.exit_code}

    def verdict(self) -> str:
        """The verdict in one line: every requirement met (with the nearest to its limit), or how many missed.

        Returns
        -------
        str
            ``every requirement met (N checked)`` with the requirement nearest to its limit and its margin in %, ``M of
            N requirements missed``, or ``no requirement checked``.
        """
        if self.requirements_met is None:
            return "no requirement checked"
        if self.requirements_met:
            least = self.summary.least_margin
            nearest = "" if least is None or least.margin_pct is None else (
                f"; the nearest to its limit by {number(least.margin_pct, '%')} %: {least.name}")
            return f"every requirement met ({len(self.requirements)} checked){nearest}"
        n = len(self.requirements)
        return f"{len(self.missed)} of {n} requirement{'s' if n != 1 else ''} missed"

    def __repr__(self) -> str:
        """The run on a screen, as python-control prints a response: the study, where its outputs went, the stages
        that ran, the verdict and each requirement with its margin (the widest line a requirement's name)."""
        ran = ", ".join(self.ran) or "nothing (every stage up to date or not applicable)"
        lines = [f"StudyResult: study {self.study.name!r}, exit code {self.exit_code}",
                 f"  outputs: {self.out}" + ("" if self.report is None else f" (report {self.report.name})"),
                 f"  ran: {ran} in {self.seconds:.1f} s",
                 f"  verdict: {self.verdict()}"]
        if self.requirements:
            lines.append("  requirements (margin as a share of the limit; achieved against required):")
            width = max(len(r.figures()) for r in self.requirements)
            lines += [f"    {r.line(width=width)}" for r in self.requirements]
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.__repr__()

    def _repr_html_(self) -> str:
        stages = "".join(f"<tr><td>{s.stage}</td><td>{f'ran in {s.seconds:.1f} s' if s.ran else s.status}</td></tr>"
                         for s in self.stages)
        reqs = "".join(f"<tr><td>{html.escape(r.name)}</td><td>{number(r.value, r.unit)} {r.unit}</td>"
                       f"<td>{r.sense.sign} {number(r.limit, r.unit)} {r.unit}</td>"
                       f"<td>{'' if r.margin_pct is None else number(r.margin_pct, '%') + ' %'}</td>"
                       f"<td>{'met' if r.met else '<b>missed</b>'}</td></tr>" for r in self.requirements)
        return (f"<p><b>Study {html.escape(self.study.name)}</b>: {html.escape(self.verdict())}; outputs in "
                f"<code>{self.out}</code>"
                f"{'' if self.report is None else f', report <code>{self.report}</code>'}</p>"
                f"<table><tr><th>stage</th><th></th></tr>{stages}</table>"
                + ("" if not reqs else
                   "<table><tr><th>requirement</th><th>achieved</th><th>required</th><th>margin</th><th></th></tr>"
                   f"{reqs}</table>"))

    def plot(self) -> Figure:
        """A Figure: each requirement's margin as a share of its limit (right of zero: met; left: missed).

        Returns
        -------
        matplotlib.figure.Figure
            One horizontal bar per requirement: its margin over its limit's magnitude (the margin itself where the limit
            is 0), green where met, red where missed.
        """
        from matplotlib.figure import Figure

        fig = Figure(figsize=(7, 0.5 + 0.35 * max(len(self.requirements), 1)))
        ax = fig.subplots()
        names = [r.name for r in self.requirements]
        shares = [r.margin / abs(r.limit) if r.limit else r.margin for r in self.requirements]
        ax.barh(names, shares, color=["tab:green" if s >= 0 else "tab:red" for s in shares])
        ax.axvline(0.0, color="0.3", lw=0.8)
        ax.set_xlabel("margin / limit (right of 0: met)")
        ax.invert_yaxis()
        fig.tight_layout()
        return fig
