"""The report's sections, each built from the study's own artifacts: its references, limits and names.

One builder per section returns a :class:`Part`: the section (paragraphs, tables, figures by
name, what it leaves out and why) and the figures to draw. A section whose stage did not run
is not built; :func:`study_section` says which stages did not apply and why. Nothing here
speaks of the paper unless the study declares the paper's numbers (``[published]``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from piezopreload.artifacts.design import DesignRecord, binding_words
from piezopreload.artifacts.gainset import GainSet, GainsTable
from piezopreload.artifacts.learning import LearningRecord
from piezopreload.artifacts.responses import ResponsesRecord
from piezopreload.artifacts.rigrun import RigRunRecord
from piezopreload.artifacts.schedule import LIFT_OFF_KEY, RIGIDITY_KEY, PreloadSchedule
from piezopreload.artifacts.system import MarginBasis, SystemRecord, TrackingNumbers
from piezopreload.artifacts.tuning import GainScheduleRecord, TuningResult
from piezopreload.models.hysteresis import CreepPI
from piezopreload.models.metrics import Signal
from piezopreload.reports import figures as F
from piezopreload.reports.document import ReportTable, Section, fmt, pct, q, ratio
from piezopreload.reports.inputs import Artifacts, ReportStudy

__all__ = ["Part", "study_section", "requirements_section", "design_section", "system_section", "learning_section",
           "feedforward_section", "controller_section", "responses_section", "rig_section",
           "provenance_section", "levels_text", "signal_name", "rigidity_words", "profile_words", "CONTROLLER_NAMES"]

CONTROLLER_NAMES = {"pid": "PID", "ff+pid": "FF + PID"}
_FRONT_WORDS = {"preload": "highest preload", "drag": "time-mean drag torque", "life": "rating life"}


def _and(words: Any) -> str:
    w = list(words)
    return w[0] if len(w) == 1 else ", ".join(w[:-1]) + " and " + w[-1]


#: the design's figure of rigidity, named apart from the controlled system's while cutting
DESIGN_RIGIDITY = "least rigidity over the duty cases at their design preloads"
_OBJECTIVE_NAMES = {"stiffness": "the least rigidity over the duty cases, maximised",
                    "drag": "the time-mean drag torque, minimised", "life": "the rating life, maximised",
                    "codesign": "chosen with its controller by the nested co-design (docs/codesign.md)"}
_METRIC_NAMES = {"rise_s": "rise time (s)", "peak_s": "peak time (s)", "settling_s": "settling time (s)"}
_KIND_NAMES = {"classical": "a classical Prandtl-Ishlinskii model (the paper's eq. 15)",
               "paper-asymmetric": "the asymmetric Prandtl-Ishlinskii model of the paper's eq. 18",
               "modified": "Kuhnen's modified Prandtl-Ishlinskii model"}


@dataclass(frozen=True)
class Part:
    """A section and the figures it names: ``(name, figure, caption)``."""

    section: Section
    figures: tuple[tuple[str, Figure, str], ...] = field(default=())


def signal_name(signal: Signal) -> str:
    return Signal(signal).words


def levels_text(reference_N: np.ndarray) -> str:
    """A reference's levels as the report names it: ``0 → 2,500 N`` for a step,
    ``60-80-100-80-60 N`` for a staircase."""
    levels = [float(reference_N[0])] + [float(b) for a, b in zip(reference_N[:-1], reference_N[1:]) if b != a]
    if len(levels) > 12:  # a ramped reference: its range
        return f"{fmt(min(levels))} to {q(max(levels), 'N')}"
    sep = " → " if len(levels) == 2 else "-"
    return sep.join(fmt(x) for x in levels) + " N"


def rigidity_words(n: TrackingNumbers) -> str:
    """The rigidity while cutting in words: its least, with the requirement at that moment, and apart from it its
    least ratio to the requirement (the requirement follows the load), with the two figures at that moment."""
    return (f"the least rigidity is {q(n.rigidity_min_cutting_N_per_um, 'N/um')} "
            f"({q(n.rigidity_required_at_min_N_per_um, 'N/um')} required at that moment) and the rigidity is at least "
            f"{ratio(n.rigidity_ratio_min)} times its requirement ({fmt(n.rigidity_at_worst_ratio_N_per_um)} against "
            f"{q(n.rigidity_required_at_worst_ratio_N_per_um, 'N/um')} at the tightest moment)")


def profile_words(design: DesignRecord) -> str:
    """The load profile the design's schedule was planned for, in words: the study's file, or the built-in machining
    cycle where the study names none (its loads are its own, not the ``[duty]`` table's), with its range of loads."""
    load = np.asarray(design.schedule.profile.axial_load_N, float)
    span = f"axial loads {fmt(float(load.min()))} to {q(float(load.max()), 'N')}"
    if design.profile == "example":
        return (f"the built-in machining cycle ({span}; the study names no [schedule] profile, and the cycle's loads "
                "are not the [duty] table's)")
    return f"the study's load profile {Path(design.profile).name} ({span})"


def _bound_words(schedule: PreloadSchedule) -> str:
    """What the schedule's lift-off bound is to the design, for a caption: its own constraint where the lift-off row
    binds the plan, else what sets the preload above it (:attr:`PreloadSchedule.binding`)."""
    binding = schedule.binding
    if LIFT_OFF_KEY in binding and RIGIDITY_KEY in binding:
        return (", the design's own constraint where the plan sits on it; under the loads where the rigidity required "
                "needs more preload, the rigidity is the design's own constraint")
    if LIFT_OFF_KEY in binding:
        return ", the design's own constraint"
    if RIGIDITY_KEY in binding:
        return (", under the schedule wherever it cuts: the rigidity required sets the preload there, the design's "
                "own constraint")
    return ", under the schedule wherever it cuts: the bolts' preload alone holds every requirement there"


def _span(values: Any, unit: str, with_unit: bool = True) -> str:
    """A range of figures by their unit's rule, ``4,958–5,169 N`` (one figure where they agree)."""
    lo, hi = fmt(float(np.min(values)), 3, unit), fmt(float(np.max(values)), 3, unit)
    return (lo if lo == hi else f"{lo}–{hi}") + (f" {unit}" if with_unit else "")


def _when(x: float | None, unit: str, never: str) -> str:
    return never if x is None else f"{fmt(x)} {unit}"


def _recorded(x: float | None) -> str:
    """A run's figure in a table cell; the responses record leaves one out where it was not finite."""
    return "not finite" if x is None else fmt(x)


# --------------------------------------------------------------------------------------
# 1. the study
# --------------------------------------------------------------------------------------
def study_section(study: ReportStudy, a: Artifacts, stage_names: tuple[str, ...]) -> Part:
    """What the study is, what its plant is, and which stages did not apply to it and why."""
    plant = a.plant
    paragraphs = [study.description] if study.description else []
    if plant is not None:
        k = plant.to_dict()["local_stiffness_N_per_um"]
        paragraphs.append(
            f"The plant is the designed preload system ([plant] from_design): {plant.rig.n_stacks} x "
            f"{plant.rig.stack.name} stacks between the two nuts, the stacks' share of the preload "
            f"0-{q(plant.stack_force_max_N, 'N')} on top of {q(plant.bolt_preload_N, 'N')} from the bolts. "
            f"The nuts' Hertz contacts make the force per volt {fmt(k['at_max'] / k['at_bolts'])} times higher "
            "at the stacks' full force than at the bolts' preload. Every control step (identification, tuning, "
            "validation, learning) ran on it.")
    else:
        paragraphs.append("The plant is the study's [rig] table; every control step (identification, tuning, "
                          "validation) ran on it.")
    skipped = [f"{name}: {a.reason(name)}" for name in stage_names if a.not_applicable(name)]
    if skipped:
        paragraphs.append("Stages that did not apply to this study: " + "; ".join(skipped) + ".")
    return Part(Section("The study", tuple(paragraphs)))


def requirements_section(a: Artifacts) -> Part | None:
    """Every requirement the stages checked: what was achieved against what was required, and the margin."""
    checked = a.requirements()
    if not checked:
        return None
    rows = tuple((r.name, q(r.value, r.unit), f"{r.sense.words} "
                  f"{q(r.limit, r.unit)}", q(r.margin, r.unit),
                  "" if r.margin_pct is None else q(r.margin_pct, "%"), "met" if r.met else "missed", r.source)
                 for r in checked)
    table = ReportTable(("requirement", "achieved", "required", "margin", "margin (% of limit)", "verdict", "set by"),
                        rows,
                        "The study's requirements, each against the worst case its run reached, with its margin in "
                        "its unit and as a share of the limit (a verdict met by a hair is missed on the next machine).",
                        "lrrrrcl", small=True)
    return Part(Section("The requirements", (), (table,)))


# --------------------------------------------------------------------------------------
# the design
# --------------------------------------------------------------------------------------
def design_section(study: ReportStudy, design: DesignRecord, system_shown: bool = False) -> Part:
    """The design optimum, its fronts, the planned schedule and the axis' natural frequency."""
    p, sch = design.point, design.schedule
    curve = design.preload_curve
    cases = f"the duty cases' design preloads, {_span(p.case_preload_N, 'N')}"
    low, high = float(np.min(sch.preload_N)), float(np.max(sch.preload_N))
    runs = f"the schedule's least and highest preload, {_span((low, high), 'N')}"

    def at(values: np.ndarray, unit: str) -> str:  # the optimum's curve at the schedule's preloads
        return _span(np.interp([low, high], curve.preload_N, values), unit, with_unit=False)

    rows = (
        ("contact angle", fmt(p.contact_angle_deg), "°", ""), ("ball diameter", fmt(p.ball_mm, 4), "mm", ""),
        ("conformity", fmt(p.conformity), "", ""), ("loaded turns per nut", f"{p.turns:.0f}", "", ""),
        ("balls per turn", f"{p.balls_per_turn:.0f}", "", ""), ("bolt preload", fmt(p.bolt_preload_N, 3, "N"), "N", ""),
        ("highest preload (stacks at full drive)", fmt(p.max_preload_N, 3, "N"), "N", ""),
        ("rigidity, unloaded, where the axis runs", at(curve.rigidity_N_per_um, "N/um"), "N/um", runs),
        ("drag torque, unloaded, where the axis runs", at(curve.drag_torque_Nm, "N m"), "N m", runs),
        (DESIGN_RIGIDITY, fmt(p.stiffness_N_per_um, 3, "N/um"), "N/um", cases),
        ("mean drag torque over the duty cycle", fmt(p.mean_drag_torque_Nm, 3, "N m"), "N m", cases),
        ("rating life over the duty cycle", fmt(p.life_h, 3, "h"), "h", cases),
        ("dynamic load rating C_dyn (estimate)", fmt(p.c_dyn_N, 3, "N"), "N", ""),
        ("peak contact pressure", fmt(p.peak_pressure_MPa, 3, "MPa"), "MPa", "the largest axial load"),
        ("lowest axial natural frequency", fmt(p.frequency_min_Hz, 3, "Hz"), "Hz", "over the table's positions"),
        ("stack stroke used", fmt(p.stack_stroke_used_um, 3, "um"), "um",
         f"from the bolts' preload to the highest, {_span((p.bolt_preload_N, p.max_preload_N), 'N')}"),
    )
    screw = ("" if study.screw_mm is None
             else f" ({q(study.screw_mm[0], 'mm')} nominal diameter, {q(study.screw_mm[1], 'mm')} lead)")
    binding = design.optimum.binding
    e = sch.energy_units
    paragraphs = [
        f"The preload design for the study's screw{screw}, solved with CasADi and IPOPT over the integer turns and "
        f"balls per turn, objective {design.optimum.objective} ({_OBJECTIVE_NAMES.get(design.optimum.objective, '')})."
        f" Constraints that bind at the optimum: {'; '.join(binding_words(binding, p)) if binding else 'none'}.",
        f"The design's least-friction preload schedule over {profile_words(design)}, {sch.preload_N.size} samples, "
        f"keeps the requirements with {fmt(sch.friction_energy_J)} {e} of friction energy per cycle, against "
        f"{fmt(sch.constant_friction_energy_J)} {e} at the best constant preload ({q(sch.constant_preload_N, 'N')}): "
        f"{pct(sch.saving_fraction)} less. That is the design's plan, before any margin a controlled loop adds"
        + ("; what the controlled system plans and achieves is in the section on the designed system." if system_shown
           else " (this study's plant is not its design: no loop followed the schedule).")]
    figures: list[tuple[str, Figure, str]] = [
        ("stiffness", F.stiffness_vs_preload(design.preload_curve, (low, high)),
         "Axial rigidity and preload drag torque of the optimum's double nut against preload; the duty cases at their "
         f"design preloads; shaded, the preloads the schedule runs ({_span((low, high), 'N')}); dotted: the bolts' "
         "preload alone, dashed: the stacks at full drive.")]
    omitted = []
    if design.fronts:
        figures.append(("pareto", F.pareto_fronts(design.fronts, p),
                        "Pareto fronts by the epsilon-constraint method (each point an optimal design): the "
                        f"{_and(_FRONT_WORDS[f.y_name] for f in design.fronts)} against the least rigidity over the "
                        "duty cases, swept up to the optimum's; star: the design optimum (objective "
                        f"{design.optimum.objective})."))
    else:
        omitted.append("Pareto fronts: the study's [design] pareto list is empty.")
    figures.append(("schedule", F.preload_schedule(sch.profile.time_s, sch.profile.axial_load_N, sch.preload_N,
                                                    sch.constant_preload_N, sch.spec.lift_off_margin),
                    f"The load profile and the design's least-friction preload schedule against the best constant "
                    f"preload ({q(sch.constant_preload_N, 'N')}); dotted, the schedule's lift-off bound "
                    f"{fmt(sch.spec.lift_off_margin)} |F_a| / 2^(3/2){_bound_words(sch)}."))
    nf = design.natural_frequency
    limit = "" if study.frequency_min_Hz is None else f"; dashed, the study's limit {q(study.frequency_min_Hz, 'Hz')}"
    figures.append(("natural-frequency", F.natural_frequency(nf.position_mm, nf.bolt_preload_Hz, nf.max_preload_Hz,
                                                             study.frequency_min_Hz),
                    "The first axial natural frequency of the table against its position, with the bolts' preload "
                    f"and with the stacks at full drive{limit}."))
    table = ReportTable(("design variable or result", "optimum", "unit", "at the preload"), rows,
                  f"The design optimum (objective: {design.optimum.objective}), each figure at the preload it is "
                  "computed for: the design's requirements at the duty cases' design preloads, and beside them the "
                  "rigidity and drag torque at the preloads the schedule runs.", "lrll")
    return Part(Section("Ball-screw preload design", tuple(paragraphs), (table,), tuple(n for n, _, _ in figures),
                        tuple(omitted)), tuple(figures))


# --------------------------------------------------------------------------------------
# the whole system and learning
# --------------------------------------------------------------------------------------
def system_section(system: SystemRecord, design: DesignRecord, learning: LearningRecord | None) -> Part:
    """The designed system along its schedule: tracking, rigidity and deflection while cutting, friction."""
    n, sch = system.numbers, design.schedule
    e = n.energy_units
    rows: list[tuple[str, str, str]] = [
        ("tracking RMS over the machining cycles" + ("" if learning is None else ", learned"),
         f"{q(n.tracking_rms_N, 'N')}", f"{q(n.tracking_rms_pct_of_range, '%')} of the schedule's "
                                       f"{q(n.schedule_range_N, 'N')} range; true force, pre-cycle left out")]
    if learning is not None:
        last = learning.last
        rows += [("learning runs' tracking RMS, before learning", f"{q(last.before_learning_rms_N, 'N')}",
                  f"{q(last.before_learning_pct_of_range, '%')} of the last pass's {q(last.span_N, 'N')} reference "
                  "range, from its first change"),
                 ("learning runs' tracking RMS, last pass's best trial", f"{q(last.tracking_rms_N, 'N')}",
                  f"{q(last.tracking_rms_pct_of_range, '%')} of that range (the section on learning)"),
                 ("learning trials (machining cycles' runs)", str(learning.trials),
                  ", ".join(f"pass {i}: {k}" for i, k in enumerate(learning.trials_per_pass, 1)))]
    deflection = ("no limit set" if n.deflection_limit_um is None else f"limit {q(n.deflection_limit_um, 'um')}")
    rows += [
        ("largest tracking error", f"{q(n.tracking_max_N, 'N')}", ""),
        ("error when the first cut begins", f"{q(n.cycle_start_error_N, 'N')}",
         f"after a {q(system.pre_cycle.duration_s, 's')} pre-cycle to the first level"),
        ("least rigidity while cutting", f"{q(n.rigidity_min_cutting_N_per_um, 'N/um')}",
         f"{q(n.rigidity_required_at_min_N_per_um, 'N/um')} required at that moment, {q(n.rigidity_min_t_s, 's')} into "
         "the run"),
        ("least rigidity over its requirement while cutting", f"{ratio(n.rigidity_ratio_min)} times",
         f"{fmt(n.rigidity_at_worst_ratio_N_per_um)} against {q(n.rigidity_required_at_worst_ratio_N_per_um, 'N/um')} "
         f"required, {q(n.rigidity_worst_t_s, 's')} into the run"
         + ("; the design's own constraint, the schedule sits on it" if RIGIDITY_KEY in sch.binding else "")),
        ("time below the required rigidity", f"{q(n.rigidity_below_requirement_s, 's')}", ""),
        ("largest nut axial deflection while cutting", f"{q(n.deflection_max_um, 'um')}",
         f"the nut alone, in the machine; {deflection}"),
        ("least preload over the schedule's lift-off bound", f"{ratio(n.lift_off_ratio_min)} times",
         f"the bound with its {fmt(n.lift_off_margin)} margin"
         + (": the design's own constraint, the schedule sits on it" if LIFT_OFF_KEY in sch.binding else
            ": a margin, the schedule is not built to sit on it")),
        *_basis_rows(system.basis),
        ("friction energy per cycle, achieved", f"{fmt(n.friction_energy_per_cycle)} {e}", "the true force"),
        ("friction energy per cycle, the loop's plan", f"{fmt(n.planned_friction_energy_per_cycle)} {e}",
         "the last pass's schedule, with its local margins and the stacks' least contact force"),
        ("friction energy per cycle, the design's plan", f"{fmt(sch.friction_energy_J)} {e}",
         "the design's least-friction schedule, before the margins"),
        ("friction energy per cycle, best constant preload", f"{fmt(sch.constant_friction_energy_J)} {e}",
         f"at {q(sch.constant_preload_N, 'N')} (the design's)"),
        ("largest local preload margin for the loop's error", f"{q(system.preload_margin_N, 'N')}",
         f"{len(system.passes)} planning pass(es)"),
    ]
    follow = ("the tuned gains with the inverse-P-I feedforward follow it" if learning is None else
              "the tuned gains with the inverse-P-I feedforward and the correction learned on each pass follow it")
    text = (f"The design's preload schedule is the reference of the force loop on the designed plant: the stacks' "
            f"share of it, over {system.cycles} machining cycles, after a {q(system.pre_cycle.duration_s, 's')} "
            f"pre-cycle that brings the stacks to the first level at the slew limit before the first cut. "
            f"Over the machining cycles {follow} within {q(n.tracking_rms_N, 'N')} RMS, "
            f"{q(n.tracking_rms_pct_of_range, '%')} of the schedule's range. While cutting, {rigidity_words(n)}. The "
            f"achieved preload needs {pct(n.friction_saved_fraction)} less friction energy than the design's best "
            f"constant preload ({fmt(n.friction_energy_per_cycle)} against {fmt(sch.constant_friction_energy_J)} {e} "
            "per cycle).")
    paragraphs = [text] + [f"What stops a requirement: {b.sentence()}." for b in system.bounds]
    ser = system.series
    fig = F.system_tracking(ser.time_s, ser.planned_N, ser.achieved_N, ser.rigidity_N_per_um, ser.required_N_per_um,
                            ser.cutting, ser.deflection_um, n.deflection_limit_um)
    caption = (f"The designed system over the pre-cycle and {system.cycles} machining cycles: the planned preload (the "
               f"schedule, local margins up to {q(system.preload_margin_N, 'N')}) and the preload the loop achieves "
               "(true force); the axial rigidity at the achieved preload under the cutting load against the "
               "requirement (dashed); the nut's axial deflection under the load"
               + (" (the study sets no limit on it)." if n.deflection_limit_um is None else
                  f" against its limit {q(n.deflection_limit_um, 'um')} (dashed)."))
    table = ReportTable(("quantity", "value", "against"), tuple(rows),
                  "The controlled preload of the designed system over the machining cycles.", "lrl")
    return Part(Section("The designed system along its preload schedule", tuple(paragraphs), (table,), ("system",)),
                (("system", fig, caption),))


def learning_section(learning: LearningRecord) -> Part:
    """Learning control on the repeated schedule: the error per trial of each margin pass, and how many trials."""
    rows = []
    for p in learning.passes:
        best = int(np.max(p.best_iteration))
        for h in p.history:
            rms = h.worst_tracking_rms_N
            rows.append((str(p.pass_number), str(h.iteration) + (" (best)" if h.iteration == best else ""),
                         fmt(rms, 3, "N"), fmt(100.0 * rms / p.span_N, 3, "%"),
                         fmt(float(np.max(h.measured_rms_N)), 3, "N")))
    last = learning.last
    per_pass = ", ".join(f"pass {p.pass_number}: {p.trials} (within 1.1 x its best from trial "
                         f"{p.trials_to_within_1p1}; stopped: {p.stop_reason})" for p in learning.passes)
    start = (f" and {q(last.history[0].worst_tracking_rms_N, 'N')} at its trial 0, which starts from the pass "
             "before's correction" if last.warm_start else "")
    contraction = last.learning.get("contraction_over_range")
    law = ("" if contraction is None else
           f" The law is checked to contract on the loop linearised over the command's range (worst "
           f"{fmt(contraction)}; below 1, the linearised loop converges monotonically).")
    text = (f"The machining cycle repeats, so the loop learns a feedforward correction from each cycle's error "
            f"({last.method} law; preview {fmt(1e3 * last.preview_s)} ms). Each trial is one run of the pass's "
            f"reference, as many machining cycles as the schedule holds; learning stops when another trial no longer "
            f"pays. {learning.trials} learning trials in all ({per_pass}).{law} Each margin pass of the schedule "
            f"learns on its own reference{', starting from what the pass before learned' if last.warm_start else ''}. "
            f"On the last pass the learning run's error (from the reference's first change, the pre-cycle's ramp "
            f"included) is {q(last.tracking_rms_N, 'N')} RMS at its best trial "
            f"({q(last.tracking_rms_pct_of_range, '%')} "
            f"of the pass's {q(last.span_N, 'N')} reference range; the causal floor of the ramped reference, which "
            f"bounds feedback alone and not a correction learned ahead of each change, is "
            f"{q(last.causal_floor_N, 'N')}), from {q(last.before_learning_rms_N, 'N')} without any learned "
            f"correction{start}. The system's own figure over the machining cycles alone is in the section on the "
            "designed system.")
    table = ReportTable(("pass", "trial", "RMS (N)", "% of range", "measured (N)"), tuple(rows),
                  "The error per learning trial (trial 0: before the pass learns, with the correction the pass "
                  "before learned where it starts from it): whole runs from the reference's first change, true force, "
                  "in % of the pass's reference range; measured: the sensor's force against the plan, what the law "
                  "learns from.", "rlrrr")
    fig = F.learning_iterations(learning.passes)
    caption = ("The error per learning trial on the repeated schedule, each margin pass on its own reference (whole "
               "runs, true force, in % of the pass's reference range); dotted: the causal floor of each pass's "
               "reference, the least error of any controller that acts only on what has happened (after each change "
               "the force waits out the loop's delay and the amplifier's slew). Learning is not bound by it: its "
               "correction is computed between trials from the whole of the last trial's error, so it moves the "
               f"command ahead of each change (preview {q(1e3 * last.preview_s, 'ms')}), which no causal controller "
               f"can (the floor with that preview: {q(last.preview_floor_N, 'N')} on the last pass).")
    return Part(Section("Learning control on the repeated schedule", (text,), (table,), ("learning",)),
                (("learning", fig, caption),))


# --------------------------------------------------------------------------------------
# the feedforward
# --------------------------------------------------------------------------------------
def feedforward_section(study: ReportStudy, a: Artifacts) -> Part:
    ff = a.feedforward
    source = ff.data
    src = ("simulated on the plant's truth model" if source.kind == "simulated"
           else f"measured, {Path(source.path or '').name}")
    kind = ff.model.kind
    with_creep = "" if not isinstance(ff.model, CreepPI) else (
        f", with creep (first-order lags of {', '.join(f'{t:g}' for t in ff.model.creep.time_constants_s)} s on the "
        "input, identified in the same QP)")
    comp = ff.compensation
    text = (f"The feedforward inverts {_KIND_NAMES.get(kind.removesuffix('+creep'), kind)} of "
            f"{ff.model.n_operators} play operators{with_creep}, its weights identified by a QP with nonnegative "
            f"weights (cvxpy + Clarabel) from the loop measurement ({src}). The model reproduces the loop within "
            f"{q(ff.fit.rms_pct, '%')} RMS ({q(ff.fit.max_pct, '%')} at worst) of the force span"
            + ("." if comp is None else  # the identify stage always checks it; a model without its check says less
               f"; the plant driven through its inverse in open loop follows the desired force within "
               f"{q(comp.rms_N, 'N')} RMS ({q(comp.max_N, 'N')} at worst)."))
    loop, comp_run = a.csv("identify", "loop"), a.csv("identify", "compensation")
    figures = (
        ("hysteresis", F.hysteresis_loops(loop["time_s"], loop["voltage_V"], loop["force_N"], loop["model_N"]),
         f"The feedforward's voltage-to-force loop measurement ({src}) and the {kind} P-I model identified from it; "
         "right, the model's error."),
        ("inverse", F.inverse_model(comp_run["desired_N"], comp_run["command_V"], comp_run["force_N"],
                                    comp_run["time_s"]),
         "The inverse P-I model (left) and the plant driven through it in open loop (right): what the feedforward "
         "alone delivers."))
    return Part(Section("Hysteresis and the feedforward", (text,), (), ("hysteresis", "inverse")), figures)


# --------------------------------------------------------------------------------------
# the controller: tuning, gain schedule, validation
# --------------------------------------------------------------------------------------
def _gains_rows(g: dict[str, Any]) -> tuple[tuple[str, str, str], ...]:
    lv = g["labview"]
    rows = [("proportional gain Kc", f"{fmt(g['Kc_V_per_N'], 4)} V/N", fmt(lv["Kc"], 4)),
            ("integral time Ti", f"{fmt(g['Ti_s'], 4)} s", f"{fmt(lv['Ti_min'], 4)} min")]
    if g["Td_s"] > 0.0:
        rows += [("derivative time Td", f"{fmt(g['Td_s'], 4)} s", f"{fmt(lv['Td_min'], 4)} min"),
                 ("derivative filter Tf", f"{fmt(g['Tf_s'], 4)} s", "not in the PID VI: filter the measurement")]
    rows += [("setpoint weight b", fmt(g["b"], 4), "not in the PID VI: weight the setpoint"),
             ("output range", f"{fmt(g['u_min_V'])} to {q(g['u_max_V'], 'V')}",
              f"{fmt(g['u_min_V'])} to {fmt(g['u_max_V'])}")]
    return tuple(rows)


#: IPOPT's return statuses in words (the solver's own names stay in tuning.json)
_SOLVER_WORDS = {"Solve_Succeeded": "solved to IPOPT's tolerance",
                 "Solved_To_Acceptable_Level": "solved to IPOPT's acceptable tolerance"}


def _capital(text: str) -> str:
    return text[:1].upper() + text[1:]


def _solver_words(text: str) -> str:
    for status, words in _SOLVER_WORDS.items():
        text = text.replace(status, words)
    return text


def _bound_text(tuning: TuningResult) -> tuple[str, tuple[str, ...]]:
    """The tuning's active bounds in words, and what is left out (the minimum-time bound, when it has none)."""
    words = ("" if not tuning.active_bounds else
             " " + " ".join(_capital(b.sentence().rstrip(".")) + "." for b in tuning.active_bounds))
    mt = tuning.minimum_time
    if mt.settling_s is None:
        return words, (f"The minimum-time bound on the step's settling: {mt.reason or 'it was not computed'}.",)
    row = tuning.row("tuned", True)
    ratio = ""
    if mt.tuned_over_bound_ratio is not None and row.settling_s is not None:
        # the bound and the ratio are of the true force; the responses' table reads the measured force
        measured = ("" if row.settling_measured_s is None else
                    f" (on the measured force, the sensors' noise included, in {q(row.settling_measured_s, 's')})")
        ratio = (f"; the tuned gains with the feedforward settle the true force in {q(row.settling_s, 's')}, "
                 f"{fmt(mt.tuned_over_bound_ratio)} times the bound{measured}")
    return words + (f" The minimum-time bound on the step's settling (the least settling any command within the "
                    f"output range gives the noise-free model's force) is {q(mt.settling_s, 's')}{ratio}."), ()


def _basis_rows(b: MarginBasis | None) -> list[tuple[str, str, str]]:
    """What the margins rest on (:class:`~piezopreload.artifacts.system.MarginBasis`), as the system table's rows."""
    if b is None:
        return []
    over = "the nominal plant" if b.lift_off_plants == 1 else f"the worst of {b.lift_off_plants} Monte Carlo plants"
    return [
        ("rigidity in the machine, where least against its requirement", q(b.rigidity_in_machine_N_per_um, "N/um"),
         f"the nut's table figure {q(b.rigidity_table_N_per_um, 'N/um')} times the vendors' in-machine factor "
         f"{fmt(b.rigidity_in_machine_factor)}; {q(b.rigidity_required_N_per_um, 'N/um')} required"),
        ("axis stiffness at the table (nut, screw, bearings)",
         f"{fmt(b.axis_stiffness_min_N_per_um)}-{q(b.axis_stiffness_max_N_per_um, 'N/um')}",
         "at that moment, over the travel"),
        ("largest axis deflection at the table while cutting", q(b.axis_deflection_max_um, "um"),
         "nut, screw and bearings, at the weakest position"),
        ("physical lift-off margin", q(b.lift_off_margin_physical_pct, "%"),
         f"by the nut law (lift-off at {fmt(b.lift_off_ratio)} F_p), {over}; "
         f"{q(b.lift_off_margin_physical_nominal_pct, '%')} on the nominal plant, "
         f"{q(b.lift_off_margin_catalogue_pct, '%')} by the catalogues' 2.83 F_p there"),
    ]


def controller_section(study: ReportStudy, a: Artifacts) -> Part:
    """The tuned gains, the gain schedule (where tuned), and their Monte Carlo validation."""
    gain_set, tuning, val = a.gain_set, a.tuning, a.validation
    g = GainsTable.from_value(gain_set.gains).to_dict()
    form = "PI" if g["Td_s"] == 0.0 else "PID"
    words, omitted = _bound_text(tuning)
    search = f" The search: {tuning.solve.search}." if tuning.solve.search else ""
    text = (f"{form} gains tuned with CasADi and IPOPT around the P-I-compensated plant (maximum sensitivity "
            f"{fmt(tuning.solve.ms)} at worst over the plant variants; solver: {_solver_words(tuning.solve.status)}); "
            f"controller form: {g['form']}.{words}{_solver_words(search)}")
    scheduled = gain_set.gains.schedule is not None
    caption = (f"The gain set ({gain_set.status}), content hash {gain_set.content_sha256} (the SHA-256 of its fields, "
               "which every artifact that uses it names; not the file's)"
               + (": the robust set, kept in it for the record; the gain schedule below is what runs." if scheduled
                  else "."))
    table = ReportTable(("parameter", "SI", "LabVIEW PID VI"), _gains_rows(g), caption, "lrr")
    parts = [s for s in (_schedule_part(tuning.solve.schedule), _validation_part(val, gain_set)) if s is not None]
    return Part(Section("The tuned controller", (text,), (table,), (), omitted, tuple(p.section for p in parts)),
                tuple(f for p in parts for f in p.figures))


def _schedule_part(schedule: GainScheduleRecord | None) -> Part | None:
    if schedule is None:
        return None
    rows = []
    worst = ("settling_s", "overshoot_N", "tracking_rms_N")
    for r in schedule.levels:
        e, rb, sc = r.entry_gains, r.robust, r.scheduled
        ms = None if r.ms is None else r.ms.get("scheduled")  # over the entry's window (a record written before: none)
        rows.append((fmt(r.level_N, 4), f"{fmt(r.window_N[0], 4)}–{fmt(r.window_N[1], 4)}",
                     fmt(1e3 * e.Kc_V_per_N, 4), fmt(1e3 * e.Ti_s, 3), fmt(e.b, 2),
                     "" if ms is None else fmt(ms, 3),
                     *(_when(x.figure(k), "", "never").strip() for x in (rb, sc) for k in worst),
                     " / ".join("yes" if x.passed else "no" for x in (rb, sc))))
    w = schedule.whole_range
    rows.append(("whole range", "", fmt(1e3 * schedule.robust.Kc_V_per_N, 4),
                 fmt(1e3 * schedule.robust.Ti_s, 3), fmt(schedule.robust.b, 2), "",
                 *(_when(x.figure(k), "", "never").strip() for x in (w.robust, w.scheduled) for k in worst),
                 " / ".join("yes" if x.passed else "no" for x in (w.robust, w.scheduled))))
    missed_by_both = [f"{fmt(r.level_N, 4)} N" for r in schedule.levels
                      if not r.robust.passed and not r.scheduled.passed]
    text = (f"A gain schedule on the preload level: {len(schedule.levels)} entries, each tuned with CasADi on its "
            "window; Kc, Ti and Td linear in the setpoint between them; the schedule and the one robust set each "
            f"validated by Monte Carlo ({schedule.plants} plants per level, the study's limits) at every level and "
            f"over the whole range. Chosen: {schedule.choice.words}, as "
            f"{schedule.reason}.")
    if missed_by_both:
        text += (f" Neither set meets the study's limits at {', '.join(missed_by_both)}: the exported gains carry that "
                 "miss, listed in the verdicts above.")
    table = ReportTable(("level (N)", "window (N)", "Kc (mV/N)", "Ti (ms)", "b", "Ms (window)", "robust: settling (s)",
                   "overshoot (N)", "tracking (N)", "schedule: settling (s)", "overshoot (N)", "tracking (N)",
                   "meets (robust / schedule)"),
                  tuple(rows), "Each schedule entry's gains, its maximum sensitivity over its own window (the worst "
                               "plant variant), and the worst case over the Monte Carlo plants at its level for the "
                               "robust set and the schedule (tracking: RMS after the changes).",
                  "ll" + "r" * 10 + "c", small=True)
    fig = F.gain_schedule(schedule)
    caption = (f"The gain schedule on the preload level ({len(schedule.levels)} entries) against the robust set "
               "(dashed), and each set's worst case over the Monte Carlo plants per level, the study's limits in red "
               "(dashed: tracking RMS, dotted: overshoot); chosen: "
               f"{schedule.choice.words}.")
    return Part(Section("The gain schedule", (text,), (table,), ("gain-schedule",)), (("gain-schedule", fig, caption),))


#: the gain schedule's choice as the report names it

#: the Monte Carlo spread's parameters as the report names them (a key not here is shown as the study names it)
_SPREAD_NAMES = {"coupling_stiffness_N_per_um": "coupling stiffness", "amp_bandwidth_Hz": "amplifier bandwidth",
                 "amp_current_limit_A": "amplifier current limit", "bw_alpha": "Bouc-Wen alpha",
                 "bw_beta_per_V": "Bouc-Wen beta", "bw_kappa": "Bouc-Wen kappa", "creep_per_decade": "creep per decade",
                 "noise_N": "sensor noise", "hertz_um_per_N23": "Hertz compliance"}
_VALIDATION_NAMES = {"settling_s": "settling time (s)", "settling_measured_s": "settling time, measured force (s)",
                     "overshoot_N": "overshoot (N)", "tracking_rms_N": "tracking RMS after changes (N)",
                     "tracking_rms_all_N": "tracking RMS, whole trajectory (N)", "peak_voltage_V": "peak command (V)"}


def _validation_part(val: Any, gain_set: GainSet) -> Part:
    limits = val.criteria.limits()
    rows = []
    for key, name in _VALIDATION_NAMES.items():
        stats = [getattr(s, key) for s in (val.worst, val.p95, val.median)]
        rows.append((name, *(_when(x, "", "never settled").strip() for x in stats),
                     fmt(limits[key]) if key in limits else "not a criterion"))
    verdict = ("every plant met every limit" if val.passed else
               f"{val.failed_plant_count} of {val.n_plants} plants missed a limit")
    spread = ", ".join(f"{_SPREAD_NAMES.get(k, k)} {pct(v)}" for k, v in val.spread.items())
    levels = (", and each preload level's, where the tuning chose between a gain schedule and the robust set"
              if isinstance((gain_set.tuning or {}).get("schedule"), dict) else "")
    text = (f"{val.n_plants} plants drawn around the nominal one (seed {val.seed}; relative spread {spread}), each run "
            f"through the study's step and trajectory with the tuned gains and the feedforward: {verdict}. "
            f"The gain set's status, from every Monte Carlo requirement of the study (the whole range's"
            f"{levels}): {gain_set.verdict()}.")
    table = ReportTable(("metric", "worst", "95th percentile", "median", "limit"), tuple(rows),
                  "The tuned gains over the Monte Carlo set of nonlinear plants.", "lrrrr")
    fig = F.monte_carlo(val)
    caption = (f"The tuned gains with the feedforward over {val.n_plants} Monte Carlo plants (seed {val.seed}): "
               f"settling time into ±{q(val.criteria.band_N, 'N')} and overshoot of the true "
               "force, and the trajectory's tracking RMS"
               + (", and the highest command over both" if "peak_voltage_V" in val.histogram_metrics() else "")
               + "; dashed, the study's limits.")
    return Part(Section("Validation", (text,), (table,), ("monte-carlo",)), (("monte-carlo", fig, caption),))


# --------------------------------------------------------------------------------------
# the responses: the study's step and trajectory, and the published numbers where declared
# --------------------------------------------------------------------------------------
def responses_section(study: ReportStudy, a: Artifacts) -> Part:
    responses = a.responses
    runs = a.response_runs()
    signal, band = responses.signal, responses.band_N
    step, traj = levels_text(runs["step"]["tuned pid"]["reference_N"]), levels_text(
        runs["trajectory"]["tuned pid"]["reference_N"])
    labels = {"study": study.gains_label, "tuned": "the tuned gains"}
    text = (f"The study's {step} step and its {traj} trajectory, each with {study.gains_label} and with the tuned "
            "gains, PID alone and with the inverse-P-I feedforward. Step times are read on the "
            f"{signal_name(signal)} against a ±{q(band, 'N')} band; tracking errors are those of the true force.")
    tables = [_responses_table(responses, labels)]
    paragraphs = [text]
    if study.published is not None and responses.reproduction:
        paragraphs.append(f"The study declares published step numbers ({study.published.source}); they stand beside "
                          f"the same controllers on this plant.")
        tables.insert(0, ReportTable(("controller", "metric", "published", study.gains_label, "tuned gains"),
                               tuple((CONTROLLER_NAMES[r.controller], _METRIC_NAMES[r.metric], fmt(r.published),
                                      _when(r.study, "", "never").strip(), _when(r.tuned, "", "never").strip())
                                     for r in responses.reproduction),
                               f"Published step numbers ({study.published.source}) against this plant's.", "llrrr"))
    creep = _creep_table(responses, labels)
    if creep is not None:
        tables.append(creep)
    step_t = float(runs["step"]["tuned pid"]["time_s"][-1])
    figures = (
        ("step", F.step_responses(runs["step"], band, signal, labels, t_max_s=step_t),
         f"The {step} step with {study.gains_label} (left) and the tuned gains (right), PID alone and with the "
         f"feedforward, {signal_name(signal)}; dashed: the ±{q(band, 'N')} band."),
        ("tracking", F.tracking(runs["trajectory"], signal, labels),
         f"The {traj} trajectory with {study.gains_label} (left) and the tuned gains (right); below, the error of the "
         "true force."))
    return Part(Section("The study's step and trajectory", tuple(paragraphs), tuple(tables), ("step", "tracking")),
                figures)


def _responses_table(responses: ResponsesRecord, labels: dict[str, str]) -> ReportTable:
    rows = []
    for run in responses.runs:
        if run.reference != "step":
            continue
        traj = responses.run(run.gains, run.controller, "trajectory")
        rows.append((labels.get(run.gains, run.gains), CONTROLLER_NAMES[run.controller],
                     _when(run.settling_s, "", "never").strip(), *(_recorded(x) for x in (
                         run.overshoot_N, traj.tracking_rms_N, traj.tracking_rms_after_change_N, run.peak_command_V))))
    return ReportTable(("gains", "controller", "settling (s)", "overshoot (N)", "RMS (N)", "RMS after changes (N)",
                  "peak (V)"), tuple(rows),
                 "Each controller on the study's step (settling time, overshoot) and trajectory (RMS error of the true "
                 "force over the whole trajectory and outside the first moments after each change), and the peak "
                 "command.", "llrrrrr")


def _creep_table(responses: ResponsesRecord, labels: dict[str, str]) -> ReportTable | None:
    rows_in = responses.creep_effect
    if not rows_in:
        return None
    by = {(r.gains, r.creep, r.reference): r for r in rows_in}
    rows = []
    for gains in dict.fromkeys(r.gains for r in rows_in):
        for creep in (False, True):
            s, t = by[(gains, creep, "step")], by[(gains, creep, "trajectory")]
            rows.append((labels.get(gains, gains), s.feedforward + (" with creep" if creep else " without creep"),
                         _when(s.settling_s, "", "never").strip(),
                         *(_recorded(x) for x in (s.overshoot_N, t.tracking_rms_N, t.tracking_rms_after_change_N))))
    return ReportTable(("gains", "feedforward", "settling (s)", "overshoot (N)", "RMS (N)", "RMS after changes (N)"),
                 tuple(rows), "FF + PID with the feedforward's creep compensation and with the same P-I model refitted "
                              "without creep, on the same noise.", "llrrrr")


# --------------------------------------------------------------------------------------
# exports and the rig run
# --------------------------------------------------------------------------------------
def _rig_rows(run: RigRunRecord) -> list[tuple[str, str]]:
    out = run.summary
    step = {"c": "compiled C (CasADi codegen)", "numpy": "numpy"}
    rows = [("status", run.status), ("cycles", str(0 if out is None else out.cycles)),
            ("controller step", "" if out is None else step.get(out.controller_step, out.controller_step))]
    m = None if out is None else out.metrics
    if out is not None and out.trip is None and m is not None:
        rows += [(label, fmt(value, 3, label.rpartition("(")[2].rstrip(")")))
                 for label, value in (("tracking RMS over the reference (N)", m.tracking_rms_N),
                                                          ("settling time (s)", m.settling_s),
                                                          ("overshoot (N)", m.overshoot_N)) if value is not None]
    if run.stall_limit is not None:
        rows.append(("stall limit (s)", f"{fmt(run.stall_limit.limit_s)} ({run.stall_limit.source})"))
    if out is not None and run.realtime:
        rows += [("missed deadlines", str(out.timing.missed_deadlines)), ("stalls", str(out.timing.stalls))]
    return rows


def _host_text(run: RigRunRecord) -> str:
    host = run.host_check
    if host is None:
        return ""
    accepted = " and was run on anyway (--accept-host)" if run.host_accepted and not host.passed else ""
    return (f" Before arming, the host check {'passed' if host.passed else 'failed'}{accepted}: wake-up lateness p99 "
            f"{fmt(1e6 * host.lateness_p99_s)} us, at most {fmt(1e3 * host.lateness_max_s)} ms, against a "
            f"{fmt(1e3 * host.budget_s)} ms budget.")


def rig_section(study: ReportStudy, a: Artifacts) -> Part:
    """The exports, and the run on the rig executor: how it ended, its figures, its limits and the host check."""
    paragraphs, omitted = [], []
    if a.has("export"):
        record = a.record("export")
        exports = [] if record is None else [Path(o.path).name for o in record.outputs.values()]
        paragraphs.append("The validated gain set was exported as " + ", ".join(exports) + ".")
    else:
        omitted.append(f"The exports: {a.reason('export')}.")
    run = a.rig_run
    if run is None:
        omitted.append(f"The rig run: {a.reason('rig')}.")
        return Part(Section("Exports and the rig run", tuple(paragraphs), (), (), tuple(omitted)))
    mode = "real time" if run.realtime else "back to back"
    head = (f"The validated gains ran on the rig executor at {run.rate_Hz:g} Hz ({mode}) against the "
            f"'{run.backend}' backend behind its interlocks (force limit "
            f"{q(run.safety.force_max_N, 'N')}), "
            f"reference {run.reference}: ")
    trip = run.trip
    if trip is not None:
        paragraphs.append(head + f"it was stopped by the interlock '{trip.cause}' at t = {q(trip.t_s, 's')} with "
                                 f"{q(trip.voltage_V, 'V')} held ({trip.detail}); the figures of a completed run do "
                                 "not apply." + _host_text(run))
    else:
        m = None if run.summary is None else run.summary.metrics
        tracking = "" if m is None or m.tracking_rms_N is None else \
            f"; the force read tracked the reference within {q(m.tracking_rms_N, 'N')} RMS"
        paragraphs.append(head + f"it completed{tracking}." + _host_text(run))
    log = a.csv("rig", "log_csv")
    fig = F.rig_run(log["time_s"], log["reference_N"], log["measured_N"], log["voltage_V"], log["mode"])
    caption = (f"The validated gains on the rig executor (backend '{run.backend}', {run.rate_Hz:g} Hz, {mode}), from "
               "its run log; grey, the ramp down to the safe voltage and disarm.")
    table = ReportTable(("quantity", "value"), tuple(_rig_rows(run)), f"The rig run (log {run.csv}).", "lr")
    return Part(Section("Exports and the rig run", tuple(paragraphs), (table,), ("rig-run",), tuple(omitted)),
                (("rig-run", fig, caption),))


# --------------------------------------------------------------------------------------
# the appendix
# --------------------------------------------------------------------------------------
def provenance_section(study: ReportStudy, a: Artifacts, stage_names: tuple[str, ...], version: str,
                       date: str) -> Part:
    """Where every number came from: the package, the study, the data, the gain set and every artifact's hash."""
    source = a.feedforward.data
    records = [r for r in (a.record(n) for n in stage_names) if r is not None]
    times = [(n, r.seconds) for n in stage_names if (r := a.record(n)) is not None and r.done and r.seconds is not None]
    rows = [("package", f"piezopreload {version}"), ("study file", study.source), ("study SHA-256", study.sha256),
            ("feedforward data", "simulated" if source.kind == "simulated" else str(source.path)),
            ("feedforward data SHA-256", source.sha256), ("gain set content hash", a.gain_set.content_sha256 or ""),
            ("report date (UTC)", date), ("stage times", ", ".join(f"{n} {t:.1f} s" for n, t in times))]
    seen: set[str] = set()
    artifacts = []
    for record in records:
        for o in record.outputs.values():
            if o.path not in seen:  # one row per file
                seen.add(o.path)
                artifacts.append((o.path, o.sha256[:24]))
    return Part(Section("Provenance", (), (
        ReportTable(("item", "value"), tuple(rows), "The study's inputs.", "ll"),
        ReportTable(("artifact", "file SHA-256 (first 24 hex digits; all 64 in pipeline.json)"), tuple(artifacts),
              "Every artifact the report read, the SHA-256 of each file as written.", "ll", small=True))))

