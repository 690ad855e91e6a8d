"""The report's first page: the design, what limits it and the verdict, then the headline figures, in words.

Where the study designs its screw, the page leads with the design (:func:`design_lead`): the screw's size
and lead, the double nut's turns and balls, the contact angle and conformity, the stacks and the preload
schedule's range, then what limits the design (the constraints that bind and the design variables held at
their bounds) and the requirements nearest their limits, each by its name in words (its key is in the section
on the requirements). The verdicts follow: each requirement missed in a sentence (achieved, required, by how
much, and its physical cause where the artifacts give one), or that every requirement checked is met, with its
robustness over the modelling assumptions where a stage recorded it. The summary then leads with what the study
exists for: on a whole-system study the schedule's tracking, the rigidity and deflection while
cutting, and the friction saved; then the controller and its validation, the study's own step,
the rig run, and the published numbers only where the study declares them. Each figure is read
from the same artifact field the section that details it reads.
"""

from __future__ import annotations

import numpy as np

from piezopreload.artifacts.design import CONSTRAINT_WORDS, VARIABLE_WORDS, DesignRecord, case_words
from piezopreload.artifacts.learning import LearningRecord
from piezopreload.artifacts.requirements import Requirement, least_margin, missed, own_constraints
from piezopreload.artifacts.responses import ResponseRun
from piezopreload.artifacts.system import SystemRecord
from piezopreload.models.thermal import ThermalMounting
from piezopreload.reports.document import fmt, pct, q
from piezopreload.reports.inputs import Artifacts, Published, ReportStudy
from piezopreload.reports.sections import levels_text, profile_words, rigidity_words, signal_name
from piezopreload.reports.thermal import thermal_lines

__all__ = ["design_lead", "verdicts", "summary"]


#: a requirement within this share of its limit is named on the first page as one that limits the design
NEAR_LIMIT_PCT = 10.0


def design_lead(study: ReportStudy, a: Artifacts) -> tuple[str, ...]:
    """The first page's account of the design: what was designed, and what limits it (empty: no design stage)."""
    design = a.design
    if design is None:
        return ()
    p, sch = design.point, design.schedule
    screw = ("" if study.screw_mm is None else
             f"on a {fmt(study.screw_mm[0])} x {q(study.screw_mm[1], 'mm')} screw (nominal diameter x lead), ")
    stacks = ""
    if study.stacks is not None:
        n, name = study.stacks
        stacks = f"; {n} x {name} piezo stack{'s' if n != 1 else ''} between the nuts"
    preload = np.asarray(sch.preload_N, dtype=float)
    levels = len(np.unique(np.round(preload)))
    lines = [
        f"The design: a double nut {screw}each nut {p.turns:.0f} loaded turns x {p.balls_per_turn:.0f} balls of "
        f"{fmt(p.ball_mm, 4, 'mm')} mm, contact angle {fmt(p.contact_angle_deg, 3, 'deg')}°, groove conformity "
        f"{fmt(p.conformity)}{stacks}: the preload {q(p.bolt_preload_N, 'N')} from the bolts alone, up to "
        f"{q(p.max_preload_N, 'N')} with the stacks at full drive. The least-friction preload schedule plans "
        f"{fmt(float(preload.min()), 3, 'N')} to {q(float(preload.max()), 'N')} ({levels} levels) over "
        f"{profile_words(design)}, against a best constant preload of {q(sch.constant_preload_N, 'N')}" + _runs(a)]
    limits = _design_limits(design.optimum.binding, p, design.optimum.objective)
    near = _near_limits(a.requirements())
    if limits or near:
        lines.append(" ".join(x for x in (limits, near) if x))
    return tuple(lines)


def _runs(a: Artifacts) -> str:
    """Where the loop runs the axis (the planned preload over the machining cycles, with its margins), or why none."""
    if a.system is None:
        return " (a plan: the study's plant is its [rig] table, and no loop follows the schedule)."
    ser, pre = a.system.series, a.system.pre_cycle.duration_s
    planned = ser.planned_N[ser.time_s >= pre]
    return (f"; with the force loop's margins the axis runs at {fmt(float(planned.min()), 3, 'N')} to "
            f"{q(float(planned.max()), 'N')} over the machining cycles.")


def _design_limits(binding: tuple[str, ...], point: object, objective: str) -> str:
    """The constraints that bind at the optimum and the variables held at their bounds, in words, without keys."""
    constraints: dict[str, list[int]] = {}
    variables = []
    for name in binding:
        base, _, rest = name.partition("[")
        if " at its " in name:
            var, _, side = name.partition(" at its ")
            name_words, unit = VARIABLE_WORDS.get(var, (var.replace("_", " "), ""))
            value = getattr(point, var, None)
            variables.append(f"{name_words} at its {side}" + ("" if value is None else f" ({fmt(value)}{unit})"))
        else:
            constraints.setdefault(base, [])
            if rest:
                constraints[base].append(int(rest.rstrip("]")))
    words = [CONSTRAINT_WORDS.get(c, (c, ""))[0].format(cases=case_words(cases)) for c, cases in constraints.items()]
    out = []
    if words:
        out.append(f"What limits the design (the constraints binding at the optimum): {'; '.join(words)}.")
    if variables:
        goal = {"stiffness": "its rigidity, the objective maximised",
                "drag": "its drag torque, the objective minimised",
                "life": "its rating life, the objective maximised"}.get(objective, f"its objective ({objective})")
        out.append(f"The optimum holds {_and(variables)}: {goal}, rests on a nut made at "
                   f"{'this bound' if len(variables) == 1 else 'these bounds'}.")
    return " ".join(out)


def _near_limits(checked: tuple[Requirement, ...]) -> str:
    """The requirements met within :data:`NEAR_LIMIT_PCT` of their limits (at least the nearest), in words."""
    met = sorted((r for r in checked if r.met and r.margin_pct is not None), key=lambda r: r.margin_pct or 0.0)
    near = [r for r in met if (r.margin_pct or 0.0) < NEAR_LIMIT_PCT] or met[:1]
    if not near:
        return ""
    words = [f"{r.name}, met by {q(r.margin_pct or 0.0, '%')}"
             + (" (a bound the least-friction schedule is planned to sit on)" if r.basis == "design" else "")
             for r in near]
    head = ("The requirement nearest its limit" if len(near) == 1 else
            f"The requirements within {q(NEAR_LIMIT_PCT, '%')} of their limits")
    return f"{head}: {'; '.join(words)}."


def _and(words: list[str]) -> str:
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]


def verdicts(a: Artifacts) -> tuple[str, ...]:
    """The requirements missed, one sentence each with its physical cause where the artifacts give it, first; or
    that every one checked is met; then the verdict's robustness over the modelling assumptions where recorded."""
    checked = a.requirements()
    if not checked:
        return ()
    miss = missed(checked)
    if not miss:
        least = least_margin(checked)
        nearest = "" if least is None else f"; the nearest to its limit: {least.sentence(source=False)}"
        own = own_constraints(checked)
        if own and least is not None and least.basis != "design":
            nearest += ("; apart from " + "; ".join(r.sentence(source=False) for r in own) +
                        (": a bound the design is built to sit on" if len(own) == 1 else
                         ": bounds the design is built to sit on"))
        lines = [f"Every requirement the study sets is met: {len(checked)} checked, each with its margin and the key "
                 f"that sets it in the section on the requirements{nearest}."]
    else:
        lines = [f"Requirement missed: {r.sentence(source=False)}{_cause(r, a)}." for r in miss]
    robust = _robustness(a)
    return tuple(lines + ([robust] if robust else []))


def _cause(r: Requirement, a: Artifacts) -> str:
    """A missed requirement's physical cause, where the artifacts hold it (the shift's heat behind its growth)."""
    t = None if a.system is None else a.system.thermal
    if t is None or not r.source.startswith("[thermal]"):
        return ""
    s, c = t.schedule, t.constant
    return (f": over the {fmt(t.shift_h)} h shift the nut's friction heat is {q(s.heat_mean_W, 'W')} at a mean "
            f"preload of {q(s.preload_mean_N, 'N')} ({q(c.heat_mean_W, 'W')} at the best constant "
            f"{q(c.preload_mean_N, 'N')}) and the support bearings' {q(s.bearing_heat_mean_W, 'W')}, warming the screw "
            f"by up to {q(s.temperature_rise_max_K, 'K')}"
            + (f", of which its pretension takes up the first {q(t.pretension_K, 'K')}"
               if t.mounting is ThermalMounting.PRETENSIONED else ""))


def _robustness(a: Artifacts) -> str:
    """The verdict's robustness over the modelling assumptions' ranges, where the system stage judged it; else
    nothing (a study without a system stage has no sensitivity study)."""
    record = None if a.system is None else a.system.sensitivity
    if record is None:
        return ""
    return f"Over the modelling assumptions: {record.sentence()} (the section on the verdicts under the assumptions)."


def summary(study: ReportStudy, a: Artifacts) -> tuple[str, ...]:
    """The study's headline figures, in the order a reader of this study asks for them."""
    lines: list[str] = []
    if a.system is not None and a.design is not None:
        lines += _system_lines(a.system, a.design, a.learning)
        if a.system.thermal is not None:
            lines += thermal_lines(a.system.thermal)
    lines.append(_controller_line(a))
    lines.append(_step_line(study, a))
    lines.append(_rig_line(a))
    if study.published is not None and a.responses.reproduction:
        lines.append(_published_line(study.published, study.gains_label, a))
    return tuple(lines)


def measured_words(learning: LearningRecord | None) -> str:
    """What the force sensors read on the last learning pass's best trial, against the plan (empty: no learning)."""
    if learning is None:
        return ""
    last = learning.last
    best = int(np.max(last.best_iteration))
    trial = next(h for h in last.history if h.iteration == best)
    return q(float(np.max(trial.measured_rms_N)), "N")


def _system_lines(system: SystemRecord, design: DesignRecord, learning: LearningRecord | None) -> list[str]:
    n, sch = system.numbers, design.schedule
    measured = measured_words(learning)
    learned = ("" if learning is None else
               f"; learning took the true error of its learning runs from "
               f"{q(learning.last.before_learning_rms_N, 'N')} "
               f"to {q(learning.last.tracking_rms_N, 'N')} RMS in {learning.trials} trials")
    deflection = ("" if n.deflection_limit_um is None else
                  f"; its largest deflection (the nut's) is {q(n.deflection_max_um, 'um')} against "
                  f"{q(n.deflection_limit_um, 'um')}")
    sensed = ("" if not measured else
              f"The force sensors read the preload within {measured} RMS of the plan (the last learning pass's best "
              "trial, the sensors' noise included); ")
    true = (f"the true preload, which no sensor reads, follows the schedule over the machining cycles within "
            f"{q(n.tracking_rms_N, 'N')} RMS ({q(n.tracking_rms_pct_of_range, '%')} of the schedule's "
            f"{q(n.schedule_range_N, 'N')} range){learned}.")
    return [
        (sensed + true) if sensed else "The designed axis: " + true,
        f"While cutting, {rigidity_words(n)}{deflection}.",
        f"The achieved preload needs {pct(n.friction_saved_fraction)} less friction energy than the design's best "
        f"constant preload ({fmt(n.friction_energy_per_cycle)} against {fmt(sch.constant_friction_energy_J)} "
        f"{n.energy_units} per cycle at {q(sch.constant_preload_N, 'N')}).",
    ]


def _controller_line(a: Artifacts) -> str:
    gains, val = a.gain_set.gains, a.validation
    if gains.schedule is not None:
        s = gains.schedule
        form = (f"gain schedule ({s.size} entries on the preload level, {fmt(min(s.levels_N))} to "
                f"{q(max(s.levels_N), 'N')}; Kc {fmt(1e3 * min(s.Kc), 4)} to {fmt(1e3 * max(s.Kc), 4)} mV/N)")
    elif gains.Td_s == 0.0:
        form = f"PI (Kc {fmt(gains.Kc, 4)} V/N, Ti {fmt(gains.Ti_s, 4)} s)"
    else:
        form = f"PID (Kc {fmt(gains.Kc, 4)} V/N, Ti {fmt(gains.Ti_s, 4)} s, Td {fmt(gains.Td_s, 4)} s)"
    w = val.worst
    settling = ("never settled on one plant at least" if w.settling_s is None
                else f"worst settling {q(w.settling_s, 's')}")
    verdict = "passed" if val.passed else f"failed on {val.failed_plant_count} of {val.n_plants} plants"
    worst = ", ".join(f"no plant's {what} was finite" if x is None else f"worst {what} {q(x, 'N')}"
                      for what, x in (("overshoot", w.overshoot_N), ("tracking RMS", w.tracking_rms_N)))
    return (f"The tuned {form} {verdict} the Monte Carlo validation on {val.n_plants} nonlinear plants: {settling}, "
            f"{worst}.")


def _step_line(study: ReportStudy, a: Artifacts) -> str:
    responses = a.responses
    runs = a.response_runs()
    step = levels_text(runs["step"]["tuned ff+pid"]["reference_N"])
    tuned, start = responses.run("tuned", "ff+pid", "step"), responses.run("study", "ff+pid", "step")

    def settle(r: ResponseRun) -> str:  # the subject is a gain set, named in the plural ("the tuned gains")
        return "do not settle" if r.settling_s is None else f"settle in {q(r.settling_s, 's')}"

    overshoot = "overshoot not finite" if tuned.overshoot_N is None else f"overshoot {q(tuned.overshoot_N, 'N')}"
    return (f"On the study's {step} step with the feedforward, the tuned gains {settle(tuned)} ({overshoot}) "
            f"and {study.gains_label} {settle(start)} ({signal_name(responses.signal)}, "
            f"±{q(responses.band_N, 'N')} band).")


def _rig_line(a: Artifacts) -> str:
    run = a.rig_run
    if run is None:
        return f"The rig run did not take place: {a.reason('rig')}."
    head = f"On the rig executor ('{run.backend}' backend, {'real time' if run.realtime else 'back to back'})"
    if run.trip is not None:
        return f"{head} the run was stopped by the interlock '{run.trip.cause}' at t = {q(run.trip.t_s, 's')}."
    m = None if run.summary is None else run.summary.metrics
    tracking = "" if m is None or m.tracking_rms_N is None else f", tracking within {q(m.tracking_rms_N, 'N')} RMS"
    return f"{head} the validated gains completed the run{tracking}."


def _published_line(published: Published, gains_label: str, a: Artifacts) -> str:
    rows = {(r.controller, r.metric): r for r in a.responses.reproduction}
    r = rows[("ff+pid", "settling_s")]
    got = "never settle" if r.study is None else f"settle in {q(r.study, 's')}"
    tuned = "never settles" if r.tuned is None else f"{q(r.tuned, 's')}"
    return (f"Published ({published.source}): the FF + PID step settles in {q(r.published, 's')}; on this plant "
            f"{gains_label} {got}, the tuned gains {tuned}.")
