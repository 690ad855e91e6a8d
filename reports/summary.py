"""The report's first page: the verdicts on the study's requirements, then its headline figures, in words.

The verdicts come first: each requirement missed in a sentence (achieved, required, by how
much), or that every requirement checked is met. The summary then leads with what the study
exists for: on a whole-system study the schedule's tracking, the rigidity and deflection while
cutting, and the friction saved; then the controller and its validation, the study's own step,
the rig run, and the published numbers only where the study declares them. Each figure is read
from the same artifact field the section that details it reads.
"""

from __future__ import annotations

from piezopreload.artifacts.design import DesignRecord
from piezopreload.artifacts.learning import LearningRecord
from piezopreload.artifacts.requirements import least_margin, missed
from piezopreload.artifacts.responses import ResponseRun
from piezopreload.artifacts.system import SystemRecord
from piezopreload.reports.document import fmt, pct
from piezopreload.reports.inputs import Artifacts, Published, ReportStudy
from piezopreload.reports.sections import levels_text, rigidity_words, signal_name
from piezopreload.reports.thermal import thermal_lines

__all__ = ["verdicts", "summary"]


def verdicts(a: Artifacts) -> tuple[str, ...]:
    """The requirements missed, one sentence each, first; or that every one checked is met."""
    checked = a.requirements()
    if not checked:
        return ()
    miss = missed(checked)
    if not miss:
        least = least_margin(checked)
        nearest = "" if least is None else f"; the nearest to its limit: {least.sentence()}"
        return (f"Every requirement the study sets is met: {len(checked)} checked, each with its margin in the "
                f"section on the requirements{nearest}.",)
    return tuple(f"Requirement missed: {r.sentence()}." for r in miss)


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


def _system_lines(system: SystemRecord, design: DesignRecord, learning: LearningRecord | None) -> list[str]:
    n, sch = system.numbers, design.schedule
    learned = ("" if learning is None else
               f"; learning took the error of its learning runs from {fmt(learning.last.before_learning_rms_N)} N to "
               f"{fmt(learning.last.tracking_rms_N)} N RMS in {learning.trials} trials")
    deflection = ("" if n.deflection_limit_um is None else
                  f"; its largest deflection is {fmt(n.deflection_max_um)} um against {fmt(n.deflection_limit_um)} um")
    return [
        f"The designed axis follows its preload schedule over the machining cycles within {fmt(n.tracking_rms_N)} N "
        f"RMS ({fmt(n.tracking_rms_pct_of_range)} % of the schedule's {fmt(n.schedule_range_N)} N range){learned}.",
        f"While cutting, {rigidity_words(n)}{deflection}.",
        f"The achieved preload needs {pct(n.friction_saved_fraction)} less friction energy than the design's best "
        f"constant preload ({fmt(n.friction_energy_per_cycle)} against {fmt(sch.constant_friction_energy_J)} "
        f"{n.energy_units} per cycle at {fmt(sch.constant_preload_N)} N).",
    ]


def _controller_line(a: Artifacts) -> str:
    gains, val = a.gain_set.gains, a.validation
    if gains.schedule is not None:
        s = gains.schedule
        form = (f"gain schedule ({s.size} entries on the preload level, {fmt(min(s.levels_N))} to "
                f"{fmt(max(s.levels_N))} N; Kc {fmt(1e3 * min(s.Kc), 4)} to {fmt(1e3 * max(s.Kc), 4)} mV/N)")
    elif gains.Td_s == 0.0:
        form = f"PI (Kc {fmt(gains.Kc, 4)} V/N, Ti {fmt(gains.Ti_s, 4)} s)"
    else:
        form = f"PID (Kc {fmt(gains.Kc, 4)} V/N, Ti {fmt(gains.Ti_s, 4)} s, Td {fmt(gains.Td_s, 4)} s)"
    w = val.worst
    settling = ("never settled on one plant at least" if w.settling_s is None
                else f"worst settling {fmt(w.settling_s)} s")
    verdict = "passed" if val.passed else f"failed on {val.failed_plant_count} of {val.n_plants} plants"
    worst = ", ".join(f"no plant's {what} was finite" if x is None else f"worst {what} {fmt(x)} N"
                      for what, x in (("overshoot", w.overshoot_N), ("tracking RMS", w.tracking_rms_N)))
    return (f"The tuned {form} {verdict} the Monte Carlo validation on {val.n_plants} nonlinear plants: {settling}, "
            f"{worst}.")


def _step_line(study: ReportStudy, a: Artifacts) -> str:
    responses = a.responses
    runs = a.response_runs()
    step = levels_text(runs["step"]["tuned ff+pid"]["reference_N"])
    tuned, start = responses.run("tuned", "ff+pid", "step"), responses.run("study", "ff+pid", "step")

    def settle(r: ResponseRun) -> str:  # the subject is a gain set, named in the plural ("the tuned gains")
        return "do not settle" if r.settling_s is None else f"settle in {fmt(r.settling_s)} s"

    overshoot = "overshoot not finite" if tuned.overshoot_N is None else f"overshoot {fmt(tuned.overshoot_N)} N"
    return (f"On the study's {step} step with the feedforward, the tuned gains {settle(tuned)} ({overshoot}) "
            f"and {study.gains_label} {settle(start)} ({signal_name(responses.signal)}, "
            f"±{fmt(responses.band_N)} N band).")


def _rig_line(a: Artifacts) -> str:
    run = a.rig_run
    if run is None:
        return f"The rig run did not take place: {a.reason('rig')}."
    head = f"On the rig executor ('{run.backend}' backend, {'real time' if run.realtime else 'back to back'})"
    if run.trip is not None:
        return f"{head} the run was stopped by the interlock '{run.trip.cause}' at t = {fmt(run.trip.t_s)} s."
    m = None if run.summary is None else run.summary.metrics
    tracking = "" if m is None or m.tracking_rms_N is None else f", tracking within {fmt(m.tracking_rms_N)} N RMS"
    return f"{head} the validated gains completed the run{tracking}."


def _published_line(published: Published, gains_label: str, a: Artifacts) -> str:
    rows = {(r.controller, r.metric): r for r in a.responses.reproduction}
    r = rows[("ff+pid", "settling_s")]
    got = "never settle" if r.study is None else f"settle in {fmt(r.study)} s"
    tuned = "never settles" if r.tuned is None else f"{fmt(r.tuned)} s"
    return (f"Published ({published.source}): the FF + PID step settles in {fmt(r.published)} s; on this plant "
            f"{gains_label} {got}, the tuned gains {tuned}.")
