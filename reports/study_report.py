"""A study's report: figures and the PDF from its artifacts, nothing recomputed.

:func:`render_report` reads what a study's stages wrote (named by the stage records of its
``pipeline.json``), draws the figures with :mod:`piezopreload.reports.figures`, writes
``report/report.json`` (every number the report shows, formatted, one builder per section)
and ``report/report.typ`` (the shipped template, or an edited one), and typesets
``report.pdf`` with Typst. What it needs of the study itself is :class:`ReportStudy`.
"""

from __future__ import annotations

import datetime as _dt
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from piezopreload.artifacts.gainset import GainSet, gains_to_dict
from piezopreload.core.artifacts import (
    atomic_write_bytes,
    atomic_write_text,
    package_version,
    read_artifact,
    write_artifact,
)
from piezopreload.core.errors import InputError
from piezopreload.reports import figures as F
from piezopreload.reports.typeset import ReportError, compile_pdf, template_text

__all__ = ["ReportStudy", "render_report", "fmt", "read_csv_columns", "FIGURES", "STAGES_READ"]

#: the figures the template names, in its order
FIGURES = ("step", "tracking", "hysteresis", "inverse", "monte-carlo", "rig-run", "stiffness", "pareto",
           "schedule", "natural-frequency", "system", "learning")
_DESIGN_FIGURES = ("stiffness", "pareto", "schedule", "natural-frequency")
#: the stages whose artifacts the report reads
STAGES_READ = ("design", "plant", "identify", "tune", "validate", "compare", "learn", "system", "export", "rig")


@dataclass(frozen=True)
class ReportStudy:
    """What the report prints of the study itself (the rest comes from the artifacts)."""

    name: str
    title: str
    path: str
    sha256: str
    source: str  # the study file as the user named it
    screw_mm: tuple[float, float] | None = None  # the design's nominal diameter and lead
    frequency_min_Hz: float | None = None  # the design's limit on the first axial mode


def fmt(x: float | None, digits: int = 3) -> str:
    """A number as the report prints it: ``digits`` significant digits (whole numbers with thousands
    separators from ``10**digits`` up); None as a dash."""
    if x is None:
        return "–"
    if abs(x) >= 10 ** digits:
        return f"{x:,.0f}"  # 13,236 rather than 1.32e+04
    return f"{x:.{digits}g}"


def read_csv_columns(path: str | Path) -> dict[str, np.ndarray]:
    """A CSV written by the pipeline (``#`` comments, one header line) as named columns."""
    with open(path, encoding="utf-8") as fh:
        lines = [line for line in fh if line.strip() and not line.startswith("#")]
    if not lines:
        raise InputError(f"{path}: no header line")
    names = lines[0].strip().split(",")
    data = np.loadtxt(lines[1:], delimiter=",", ndmin=2) if len(lines) > 1 else np.empty((0, len(names)))
    if data.shape[1] != len(names):
        raise InputError(f"{path}: {data.shape[1]} columns but the header names {len(names)}")
    return {name: data[:, j] for j, name in enumerate(names)}


class _Reader:
    def __init__(self, out: Path, records: dict[str, dict[str, Any]]) -> None:
        self.out, self.records = out, records

    def path(self, stage: str, label: str) -> Path:
        rec = self.records.get(stage, {})
        if rec.get("status") != "done" or label not in rec.get("outputs", {}):
            raise InputError(f"{self.out}: the stage '{stage}' has no output '{label}'; run the study again")
        return self.out / rec["outputs"][label]["path"]

    def has(self, stage: str) -> bool:
        return self.records.get(stage, {}).get("status") == "done"


_CONTROLLER_NAMES = {"pid": "PID", "ff+pid": "FF + PID"}
_METRIC_NAMES = {"rise_s": "rise time (s)", "peak_s": "peak time (s)", "settling_s": "settling time (s)"}


def render_report(out: Path, records: dict[str, dict[str, Any]], study: ReportStudy, *,
                  say: Callable[[str], None], bar: Callable[[int, int], None],
                  template: str | None = None) -> tuple[dict[str, Path], dict[str, Any]]:
    """Figures, ``report/report.json``, ``report/report.typ`` and ``report.pdf`` in ``out``.

    ``records`` are the stages' records (their outputs' paths); ``template`` a Typst
    template's text (default: the shipped one); ``say`` gets messages, ``bar`` the figures drawn.
    """
    r = _Reader(out, records)
    folder = out / "report"
    figdir = folder / "figures"
    written: dict[str, Path] = {}
    captions: dict[str, str] = {}
    pending: list[tuple[Any, Path]] = []  # drawn together at the end (F.save_all)

    def put(name: str, fig: Any, caption: str) -> None:
        written[f"figure-{name}"] = figdir / f"{name}.pdf"
        pending.append((fig, written[f"figure-{name}"]))
        captions[name] = caption

    # ---- responses -------------------------------------------------------------------------
    responses = read_artifact(r.path("compare", "responses"), "responses")
    signal, band = responses["signal"], float(responses["band_N"])
    runs: dict[str, dict[str, dict[str, np.ndarray]]] = {"step": {}, "trajectory": {}}
    for run in responses["runs"]:
        runs[run["reference"]][f"{run['gains']} {run['controller']}"] = read_csv_columns(out / run["csv"])
    put("step", F.step_responses(runs["step"], band, signal),
        f"The {_levels(runs['step'])} N step with the paper's gains (left; the paper's Figures 10 and 13) and the tuned "
        f"gains (right), PID alone and with the inverse-P-I feedforward, {signal.replace('_N', '')} force; dashed: "
        f"the ±{band:g} N band.")
    put("tracking", F.tracking(runs["trajectory"], signal),
        f"The {_levels(runs['trajectory'])} N staircase (the paper's Figures 11 and 14): the paper's gains (left) and the "
        "tuned gains (right); below, the error of the true force.")

    # ---- feedforward -------------------------------------------------------------------------
    ff_doc = read_artifact(r.path("identify", "model"), "hysteresis-model")
    loop = read_csv_columns(r.path("identify", "loop"))
    comp = read_csv_columns(r.path("identify", "compensation"))
    source = ff_doc["inputs"]["data"]
    src_text = ("simulated on the rig's truth model" if source["kind"] == "simulated"
                else f"measured, {Path(source['path']).name}")
    n_ops = len(ff_doc["model"].get("thresholds", []))
    put("hysteresis", F.hysteresis_loops(loop["time_s"], loop["voltage_V"], loop["force_N"], loop["model_N"], src_text),
        f"The feedforward's voltage-to-force loop measurement ({src_text}) and the {ff_doc['model']['kind']} P-I model "
        "identified from "
        f"it (the paper's Figures 4 and 5); right, the model's error.")
    put("inverse", F.inverse_model(comp["desired_N"], comp["command_V"], comp["force_N"], comp["time_s"]),
        "The inverse P-I model (left; the paper's Figure 6) and the rig driven through it in open loop (right): "
        "what the feedforward alone delivers.")

    # ---- validation, rig ---------------------------------------------------------------------
    val = read_artifact(r.path("validate", "validation"), "validation")
    crit = val["criteria"]
    put("monte-carlo", F.monte_carlo(val["metrics"], {"settling_s": crit["settling_max_s"],
                                                      "overshoot_N": crit["overshoot_max_N"],
                                                      "tracking_rms_N": crit["tracking_rms_max_N"]}),
        f"The tuned gains with the feedforward over {val['n_plants']} Monte Carlo rigs (seed {val['seed']}): settling "
        f"time into ±{crit['band_N']:g} N and overshoot of the true force, and the trajectory's tracking RMS; dashed, "
        "the validation limits.")
    tuning_doc = read_artifact(r.path("tune", "tuning"), "tuning")
    schedule = tuning_doc["tuning"].get("schedule")
    if schedule is not None:
        put("gain-schedule", F.gain_schedule(schedule),
            f"The gain schedule on the preload level ({len(schedule['levels'])} entries, each tuned on its window) "
            "against the one robust set (dashed), and each set's worst case over "
            f"{schedule['plants']} Monte Carlo rigs per level; chosen: {schedule['choice']}.")
    log = read_csv_columns(r.path("rig", "log_csv"))
    sidecar = read_artifact(r.path("rig", "log_json"), "rig-run")
    put("rig-run", F.rig_run(log["time_s"], log["reference_N"], log["measured_N"], log["voltage_V"], log["mode"]),
        f"The validated gains on the rig executor (backend '{sidecar['backend']}', {sidecar['rate_Hz']:g} Hz, "
        f"{'real time' if sidecar['realtime'] else 'back to back'}), from its run log; grey, the ramp down to "
        "the safe voltage and disarm.")

    # ---- design --------------------------------------------------------------------------------
    design = read_artifact(r.path("design", "design"), "design") if r.has("design") else None
    if design is not None:
        point = design["optimum"]["point"]
        curve = design.get("preload_curve")
        if curve is None:
            raise InputError(f"{r.path('design', 'design')}: field 'preload_curve' is missing; run the study again")
        put("stiffness", F.stiffness_vs_preload(curve),
            "Axial rigidity and preload drag torque of the optimum's double nut against preload; the duty cases at "
            "their preloads.")
        put("pareto", F.pareto_fronts(design["fronts"], point),
            "Pareto fronts by the epsilon-constraint method (each point an optimal design); star: the optimum.")
        s = design["schedule"]
        put("schedule", F.preload_schedule(np.asarray(s["time_s"]), np.asarray(s["axial_load_N"]),
                                           np.asarray(s["preload_N"]), float(s["constant_preload_N"])),
            f"The load profile and the least-friction preload schedule against the best constant preload: "
            f"{100 * s['saving_fraction']:.0f} % less friction energy.")
        nf = design["natural_frequency"]
        put("natural-frequency", F.natural_frequency(np.asarray(nf["position_mm"]), np.asarray(nf["bolt_preload_Hz"]),
                                                     np.asarray(nf["max_preload_Hz"]),
                                                     study.frequency_min_Hz),
            "The first axial natural frequency of the table against its position, with the bolts' preload and "
            "with the stacks at full drive.")

    # ---- the whole system ----------------------------------------------------------------------
    system = read_artifact(r.path("system", "system"), "system") if r.has("system") else None
    plant = read_artifact(r.path("plant", "plant"), "plant") if r.has("plant") else None
    if system is not None:
        ser = {k: np.asarray(v, float) for k, v in system["series"].items()}
        put("system", F.system_tracking(ser["time_s"], ser["planned_N"], ser["achieved_N"], ser["rigidity_N_per_um"],
                                        ser["required_N_per_um"], ser["cutting"], ser["deflection_um"],
                                        system.get("deflection_limit_um")),
            f"The designed system over {system['cycles']} machining cycles: the planned preload (the schedule, "
            f"margin {fmt(system['preload_margin_N'])} N) and the preload the tuned loop achieves (true force); the "
            "axial rigidity at the achieved preload under the cutting load against the requirement; the axial "
            "deflection under the load.")

    learning = read_artifact(r.path("learn", "learning"), "learning") if r.has("learn") else None
    if learning is not None:
        put("learning", F.learning_iterations(learning["pass_records"]),
            "The error per learning iteration on the repeated schedule, each margin pass of the schedule on its own "
            "reference (whole cycles, true force, in % of the schedule's range); dotted: the causal floor of the "
            "ramped reference (the delay's lag at each change of slope).")

    F.save_all(pending, progress=bar)

    # ---- report.json -----------------------------------------------------------------------------
    gain_set = GainSet.load(r.path("validate", "gains"))
    tuning = read_artifact(r.path("tune", "tuning"), "tuning")
    now = _dt.datetime.now(_dt.UTC).replace(microsecond=0)
    data = _report_data(study, records, responses, ff_doc, n_ops, src_text, gain_set, tuning, val, sidecar, design, now)
    data["system"] = None if system is None else _system_section(system, plant, tuning, learning, design)
    data["learning"] = None if learning is None else _learning_section(learning)
    data["figures"] = {name: {"file": f"figures/{name}.pdf", "caption": captions[name]} for name in captions}
    write_artifact(folder / "report.json", "report", data)
    atomic_write_text(folder / "report.typ", template if template is not None else template_text())
    try:
        pdf = compile_pdf(folder / "report.typ", date=now)
    except ReportError as exc:
        raise InputError(str(exc)) from None
    atomic_write_bytes(out / "report.pdf", pdf)
    written.update({"report": out / "report.pdf", "report_json": folder / "report.json",
                    "template": folder / "report.typ"})
    say(f"wrote {out / 'report.pdf'} ({len(pdf) / 1024:.0f} kB, {len(captions)} figures)")
    return written, {"figures": list(captions), "pdf_bytes": len(pdf)}


def _levels(runs: dict[str, dict[str, np.ndarray]]) -> str:
    ref = next(iter(runs.values()))["reference_N"]
    levels = [ref[0]] + [b for a, b in zip(ref[:-1], ref[1:]) if b != a]
    return "-".join(f"{x:g}" for x in levels) if len(levels) > 2 else " → ".join(f"{x:g}" for x in levels)


def _report_data(study: ReportStudy, records: dict[str, dict[str, Any]], responses: dict[str, Any],
                 ff_doc: dict[str, Any], n_ops: int, src_text: str, gain_set: GainSet,
                 tuning: dict[str, Any], val: dict[str, Any], sidecar: dict[str, Any],
                 design: dict[str, Any] | None, now: _dt.datetime) -> dict[str, Any]:
    """Every number the report shows, formatted: one builder per section of the template."""
    rig_sum = records["rig"]["summary"]
    summary = _summary_lines(responses, gain_set, val, sidecar, rig_sum)
    design_data = None
    if design is not None:
        design_data = _design_section(study, design)
        p, sch = design["optimum"]["point"], design["schedule"]
        summary.append(
            f"Design optimum ({design['optimum']['objective']}): {p['turns']:.0f} turns of {p['balls_per_turn']:.0f} "
            f"balls of {fmt(p['ball_mm'])} mm at {fmt(p['contact_angle_deg'])}°, least rigidity "
            f"{fmt(p['stiffness_N_per_um'])} N/um; the preload schedule needs {100 * sch['saving_fraction']:.0f} % less "
            "friction energy than the best constant preload.")
    return {
        "title": study.title or f"Study {study.name}",
        "study": {"name": study.name, "path": study.path, "sha256": study.sha256},
        "summary": summary,
        "reproduction": {"rows": [[_CONTROLLER_NAMES[r["controller"]], _METRIC_NAMES[r["metric"]], fmt(r["paper"]),
                                   fmt(r["reproduction"]), fmt(r["tuned"])] for r in responses["reproduction"]],
                         "signal": signal_name(responses["signal"]), "band": f"{fmt(responses['band_N'])} N"},
        "responses": {"rows": _response_rows(responses)},
        "creep": _creep_section(responses),
        "feedforward": {"text": _feedforward_text(ff_doc, n_ops, src_text)},
        "gains": _gains_section(gain_set, tuning),
        "schedule": _schedule_section(tuning["tuning"].get("schedule")),
        "validation": _validation_section(val),
        "rig": _rig_section(records, sidecar, rig_sum),
        "design": design_data,
        "provenance": _provenance(study, records, ff_doc, src_text, gain_set, now),
        "inputs": {"gain_set_sha256": gain_set.content_sha256, "study_sha256": study.sha256},
    }


def _summary_lines(responses: dict[str, Any], gain_set: GainSet, val: dict[str, Any], sidecar: dict[str, Any],
                   rig_sum: dict[str, Any]) -> list[str]:
    by = {(r["gains"], r["controller"], r["reference"]): r for r in responses["runs"]}
    g, s = gains_to_dict(gain_set.gains), val["summary"]
    tuned_ff, paper_ff = by[("tuned", "ff+pid", "step")], by[("paper", "ff+pid", "step")]
    paper_settling = next(r["paper"] for r in responses["reproduction"]
                          if r["controller"] == "ff+pid" and r["metric"] == "settling_s")
    return [
        f"The paper's FF + PID step settles in {fmt(paper_settling)} s; on the calibrated rig "
        f"its gains settle in {fmt(paper_ff['settling_s'])} s and the tuned gains in {fmt(tuned_ff['settling_s'])} s "
        f"({signal_name(responses['signal'])}, ±{fmt(responses['band_N'])} N band).",
        f"On the staircase trajectory the tracking RMS is {fmt(by[('paper', 'ff+pid', 'trajectory')]['tracking_rms_N'])} N "
        f"with the paper's gains and {fmt(by[('tuned', 'ff+pid', 'trajectory')]['tracking_rms_N'])} N with the tuned "
        "gains, both with the feedforward.",
        f"The tuned gains (Kc {fmt(g['Kc_V_per_N'], 4)} V/N, Ti {fmt(g['Ti_s'], 4)} s, Td {fmt(g['Td_s'], 4)} s) "
        f"{'passed' if val['passed'] else 'failed'} validation on {val['n_plants']} nonlinear rigs: worst settling "
        f"{fmt(s['settling_s']['worst'])} s, worst overshoot {fmt(s['overshoot_N']['worst'])} N.",
        f"On the rig executor ({sidecar['backend']}) the run {sidecar['status']}: settling "
        f"{fmt(rig_sum.get('settling_s'))} s, overshoot {fmt(rig_sum.get('overshoot_N'))} N.",
    ]


def _response_rows(responses: dict[str, Any]) -> list[list[str]]:
    rows = []
    for run in responses["runs"]:
        if run["reference"] != "step":
            continue
        traj = next(t for t in responses["runs"] if t["reference"] == "trajectory" and t["gains"] == run["gains"]
                    and t["controller"] == run["controller"])
        rows.append([run["gains"], _CONTROLLER_NAMES[run["controller"]], fmt(run["settling_s"]),
                     fmt(run["overshoot_N"]), fmt(traj["tracking_rms_N"]), fmt(traj["tracking_rms_after_change_N"]),
                     fmt(run["peak_command_V"])])
    return rows


def _creep_section(responses: dict[str, Any]) -> dict[str, Any] | None:
    """FF + PID with and without the feedforward's creep compensation (None when the study's feedforward has no creep)."""
    rows_in = responses.get("creep_effect")
    if not rows_in:
        return None
    by = {(r["gains"], r["creep"], r["reference"]): r for r in rows_in}
    rows = []
    for gains in dict.fromkeys(r["gains"] for r in rows_in):
        for creep in (False, True):
            step, traj = by[(gains, creep, "step")], by[(gains, creep, "trajectory")]
            rows.append([gains, step["feedforward"], fmt(step["settling_s"]), fmt(step["overshoot_N"]),
                         fmt(traj["tracking_rms_N"]), fmt(traj["tracking_rms_after_change_N"])])
    return {"rows": rows}


_KIND_NAMES = {"classical": "a classical Prandtl-Ishlinskii model (eq. 15)",
               "paper-asymmetric": "the paper's asymmetric Prandtl-Ishlinskii model (eq. 18)",
               "modified": "Kuhnen's modified Prandtl-Ishlinskii model"}


def _feedforward_text(ff_doc: dict[str, Any], n_ops: int, src_text: str) -> str:
    ident = ff_doc["identification"]
    fit = ident["fit"]
    kind = str(ff_doc["model"].get("kind", "classical"))
    creep = ff_doc["model"].get("creep")
    with_creep = "" if not creep else (
        f", with creep (first-order lags of {', '.join(f'{t:g}' for t in creep['time_constants_s'])} s on the input, "
        "identified in the same QP; the same model refitted without creep is compared in the first section)")
    return (f"The feedforward inverts {_KIND_NAMES.get(kind.removesuffix('+creep'), kind)} of {n_ops} play operators "
            f"with the paper's thresholds (its eq. 16){with_creep}, its weights identified by a QP with nonnegative "
            f"weights (cvxpy + Clarabel) from "
            f"the loop measurement ({src_text}). The model reproduces the loop within {fmt(fit['rms_pct'])} % RMS "
            f"({fmt(fit['max_pct'])} % at worst) of the force span; the rig driven through its inverse in open loop "
            f"follows the desired force within {fmt(ident['compensation_rms_N'])} N RMS "
            f"({fmt(ident['compensation_max_N'])} N at worst).")


def _gains_section(gain_set: GainSet, tuning: dict[str, Any]) -> dict[str, Any]:
    g = gains_to_dict(gain_set.gains)
    lv = g["labview"]
    rows = [
        ["proportional gain Kc", f"{fmt(g['Kc_V_per_N'], 4)} V/N", fmt(lv["Kc"], 4)],
        ["integral time Ti", f"{fmt(g['Ti_s'], 4)} s", f"{fmt(lv['Ti_min'], 4)} min"],
        ["derivative time Td", f"{fmt(g['Td_s'], 4)} s", f"{fmt(lv['Td_min'], 4)} min"],
        ["derivative filter Tf", f"{fmt(g['Tf_s'], 4)} s", "–"],
        ["setpoint weight b", fmt(g["b"], 4), "–"],
        ["output range", f"{fmt(g['u_min_V'])} to {fmt(g['u_max_V'])} V", f"{fmt(g['u_min_V'])} to {fmt(g['u_max_V'])}"],
    ]
    return {"rows": rows, "status": gain_set.status, "sha256": gain_set.content_sha256,
            "text": (f"PID gains tuned with CasADi and IPOPT around the P-I-compensated rig (maximum sensitivity "
                     f"{fmt(tuning['tuning']['ms'])}, {tuning['tuning']['status']}); controller form: {g['form']}. "
                     f"The minimum-time bound on the step's settling is {fmt(tuning['minimum_time']['settling_s'])} s; "
                     f"the tuned settling is {fmt(tuning['minimum_time']['tuned_over_bound_ratio'])} times it.")}


def _schedule_section(schedule: dict[str, Any] | None) -> dict[str, Any] | None:
    """The gain schedule table: per level the entry's gains and both sets' worst cases; the choice and why."""
    if schedule is None:
        return None
    rows = []
    for r in schedule["levels"]:
        e, rb, sc = r["entry"], r["robust"], r["scheduled"]
        rows.append([fmt(r["level_N"], 4), f"{fmt(r['window_N'][0], 4)}–{fmt(r['window_N'][1], 4)}",
                     fmt(1e3 * e["Kc_V_per_N"], 4), fmt(1e3 * e["Ti_s"], 3), fmt(1e3 * e["Td_s"], 3),
                     *(f"{fmt(x[k])}" for x in (rb, sc) for k in ("settling_s", "overshoot_N", "tracking_rms_N")),
                     " / ".join("yes" if x["passed"] else "no" for x in (rb, sc))])
    w, rb = schedule["whole_range"], schedule["robust"]
    rows.append(["whole range", "study's", fmt(1e3 * rb["Kc_V_per_N"], 4), fmt(1e3 * rb["Ti_s"], 3),
                 fmt(1e3 * rb["Td_s"], 3),
                 *(f"{fmt(w[x][k])}" for x in ("robust", "scheduled") for k in ("settling_s", "overshoot_N", "tracking_rms_N")),
                 " / ".join("yes" if w[x]["passed"] else "no" for x in ("robust", "scheduled"))])
    return {"rows": rows, "choice": schedule["choice"], "text": (
        f"Gains scheduled on the preload level: {len(schedule['levels'])} entries, each tuned with CasADi on a step "
        "across its window and a staircase inside it (the robust set's Tf and b held), Kc, Ti and Td linear in the "
        "setpoint between them; the schedule and the one robust set each validated by Monte Carlo "
        f"({schedule['plants']} rigs per level, the study's limits) at every level and over the whole range. "
        f"Chosen: {schedule['choice']}: {schedule['reason']}.")}


_VALIDATION_NAMES = {"settling_s": "settling time (s)", "settling_measured_s": "settling time, measured force (s)",
                     "overshoot_N": "overshoot (N)", "tracking_rms_N": "tracking RMS after changes (N)",
                     "tracking_rms_all_N": "tracking RMS, whole trajectory (N)", "peak_voltage_V": "peak command (V)"}


def _validation_section(val: dict[str, Any]) -> dict[str, Any]:
    s, c = val["summary"], val["criteria"]
    limits = {"settling_s": c["settling_max_s"], "overshoot_N": c["overshoot_max_N"],
              "tracking_rms_N": c["tracking_rms_max_N"], "peak_voltage_V": c["peak_voltage_max_V"]}
    rows = [[name, fmt(s[k]["worst"]), fmt(s[k]["p95"]), fmt(s[k]["p50"]), fmt(limits.get(k))]
            for k, name in _VALIDATION_NAMES.items() if k in s]
    verdict = "every plant met every limit" if val["passed"] else f"{len(val['failures'])} misses"
    return {"rows": rows, "text": (
        f"{val['n_plants']} rigs drawn around the nominal one (seed {val['seed']}; relative spread "
        + ", ".join(f"{k} {fmt(v)}" for k, v in val["spread"].items())
        + f"), each run through the step and the trajectory with the tuned gains and the feedforward: {verdict}.")}


def _rig_section(records: dict[str, dict[str, Any]], sidecar: dict[str, Any], rig_sum: dict[str, Any]) -> dict[str, Any]:
    rows = [["status", sidecar["status"]], ["cycles", str(rig_sum["cycles"])],
            ["controller step", {"c": "compiled C (CasADi codegen)", "numpy": "numpy"}.get(
                rig_sum["controller_step"], rig_sum["controller_step"])],
            ["settling time (s)", fmt(rig_sum.get("settling_s"))], ["overshoot (N)", fmt(rig_sum.get("overshoot_N"))],
            ["tracking RMS over the reference (N)", fmt(rig_sum.get("tracking_rms_N"))],
            ["missed deadlines", str(rig_sum["missed_deadlines"])]]
    exports = [o["path"] for o in records.get("export", {}).get("outputs", {}).values()]
    return {"rows": rows, "backend": sidecar["backend"], "text": (
        "The validated gain set exported as " + ", ".join(Path(e).name for e in exports)
        + f", and run on the rig executor at {sidecar['rate_Hz']:g} Hz against the '{sidecar['backend']}' backend "
          "behind its interlocks; the run log is " + Path(records['rig']['outputs']['log_csv']['path']).as_posix() + ".")}


def _design_section(study: ReportStudy, design: dict[str, Any]) -> dict[str, Any]:
    p, sch = design["optimum"]["point"], design["schedule"]
    rows = [
        ["contact angle", fmt(p["contact_angle_deg"]), "°"], ["ball diameter", fmt(p["ball_mm"], 4), "mm"],
        ["conformity", fmt(p["conformity"]), "–"], ["loaded turns per nut", f"{p['turns']:.0f}", "–"],
        ["balls per turn", f"{p['balls_per_turn']:.0f}", "–"], ["bolt preload", fmt(p["bolt_preload_N"], 4), "N"],
        ["maximum (piezo) preload", fmt(p["max_preload_N"], 4), "N"],
        ["least rigidity over the duty cycle", fmt(p["stiffness_N_per_um"], 4), "N/um"],
        ["mean drag torque", fmt(p["mean_drag_torque_Nm"]), "N m"], ["rating life", fmt(p["life_h"], 4), "h"],
        ["C_dyn (estimate)", fmt(p["c_dyn_N"], 4), "N"], ["peak contact pressure", fmt(p["peak_pressure_MPa"], 4), "MPa"],
        ["lowest axial natural frequency", fmt(p["frequency_min_Hz"], 4), "Hz"],
        ["stack stroke used", fmt(p["stack_stroke_used_um"]), "um"],
    ]
    diameter, lead = study.screw_mm or (None, None)
    return {
        "objective": design["optimum"]["objective"], "rows": rows, "binding": design["optimum"]["binding"] or ["none"],
        "text": (f"The preload design for the study's screw ({fmt(diameter)} mm "
                 f"nominal diameter, {fmt(lead)} mm lead), solved with CasADi and "
                 f"IPOPT over the integer turns and balls per turn; Pareto fronts by the epsilon-constraint method "
                 f"({', '.join(f['pair'] for f in design['fronts'])}); the preload schedule over the load profile "
                 f"keeps the rigidity above its target at {fmt(sch['friction_energy'], 4)} J of friction energy, "
                 f"against {fmt(sch['constant_friction_energy'], 4)} J at the best constant preload "
                 f"({fmt(sch['constant_preload_N'], 4)} N)."),
    }


def _system_section(system: dict[str, Any], plant: dict[str, Any] | None, tuning: dict[str, Any],
                    learning: dict[str, Any] | None = None, design: dict[str, Any] | None = None) -> dict[str, Any]:
    """The whole system: tracking of the schedule, rigidity and deflection while cutting, friction energy, the gains."""
    e = system["energy_units"]
    before = [] if learning is None else [
        ["tracking RMS before learning", f"{fmt(learning['before_learning_rms_N'])} N",
         f"{fmt(learning['before_learning_pct_of_range'])} % of the range (the last pass's reference)"]]
    rows = [
        ["tracking RMS (true force)" + ("" if learning is None else ", learned"), f"{fmt(system['tracking_rms_N'])} N",
         f"{fmt(system['tracking_rms_pct_of_range'])} % of {fmt(system['schedule_range_N'])} N"], *before,
        ["largest tracking error", f"{fmt(system['tracking_max_N'])} N", ""],
        ["least rigidity / requirement while cutting", f"{fmt(system['rigidity_min_cutting_N_per_um'])} N/um",
         f"required {fmt(system['rigidity_required_N_per_um'])} N/um (ratio {fmt(system['rigidity_ratio_min'])})"],
        ["time below the requirement", f"{fmt(system['rigidity_below_requirement_s'])} s", ""],
        ["largest axial deflection while cutting", f"{fmt(system['deflection_max_um'])} um",
         f"limit {fmt(system['deflection_limit_um'])} um"],
        ["friction energy per cycle, achieved", f"{fmt(system['friction_energy_per_cycle'])} {e}",
         f"planned {fmt(system['planned_friction_energy_per_cycle'])} {e}"],
        *([] if design is None else [  # the best constant preload is the design's (recorded there only)
            ["friction energy per cycle, best constant preload",
             f"{fmt(design['schedule']['constant_friction_energy'])} {e}",
             f"{fmt(design['schedule']['constant_preload_N'])} N"]]),
        ["preload margin left for the loop", f"{fmt(system['preload_margin_N'])} N",
         f"{len(system['passes'])} pass(es)"],
    ]
    saving = system["friction_saved_fraction"]
    text = (f"The design's preload schedule is the reference of the force loop on the designed plant: the stacks' share "
            f"(the schedule less the bolts' preload), over {system['cycles']} machining cycles. The tuned gains with the "
            + ("inverse-P-I feedforward (no preview, no learning) follow it" if learning is None else
               f"inverse-P-I feedforward and the correction learned over {learning['iterations']} iterations per pass "
               f"(from {fmt(learning['before_learning_pct_of_range'])} % of the range before learning) follow it") +
            f" within {fmt(system['tracking_rms_N'])} N RMS, "
            f"{fmt(system['tracking_rms_pct_of_range'])} % of its range; the axis keeps at least "
            f"{fmt(system['rigidity_ratio_min'])} times the rigidity it needs while cutting, and the achieved preload "
            f"needs {100 * saving:.0f} % less friction energy than the best constant preload.")
    gains = ""
    if plant is not None:
        k = plant["local_stiffness_N_per_um"]
        ratio = k["at_max"] / k["at_bolts"]
        ms = tuning.get("tuning", {}).get("ms")
        gains = (f"Gains over the preload range: the nuts' Hertz contacts make the force per volt {fmt(ratio)} times "
                 f"higher at the stacks' full force ({fmt(k['at_max'])} N/um of stroke) than at the bolts' preload "
                 f"({fmt(k['at_bolts'])} N/um). The tuning bounds the maximum sensitivity at both ends of that range "
                 f"on every plant variant (Ms {fmt(ms)}) and the Monte Carlo validation runs the whole range, so one "
                 "robust gain set meets the specification: no gain schedule is needed, and the exports hold that set.")
    return {"text": text, "gains": gains, "rows": rows}


def _learning_section(learning: dict[str, Any]) -> dict[str, Any]:
    """Learning control on the repeated schedule: the error per iteration of each margin pass."""
    rows = []
    for p in learning["pass_records"]:
        span = p["tracking_rms_N"] / p["tracking_rms_pct_of_range"] * 100.0 if p["tracking_rms_pct_of_range"] else 1.0
        best = int(np.max(p["best_iteration"]))
        for h in p["history"]:
            rms = float(np.max(h["tracking_rms_N"]))
            rows.append([str(p["pass"]), str(h["iteration"]) + (" (best)" if h["iteration"] == best else ""),
                         fmt(rms), fmt(100.0 * rms / span), fmt(float(np.max(h["measured_rms_N"])))])
    text = (f"The machining cycle repeats, so the loop learns a feedforward correction from each cycle's error "
            f"({learning['method']} law; preview {fmt(1e3 * learning['preview_s'])} ms). The law is checked to contract "
            f"on the loop linearised over the command's range (worst {fmt(learning['contraction_over_range'])}, below 1: "
            "monotone convergence of the linearised loop). Each margin pass of the schedule learns on its own reference, "
            f"so the margin is planned from the learned loop's error. On the last pass the error falls from "
            f"{fmt(learning['before_learning_rms_N'])} N to {fmt(learning['tracking_rms_N'])} N RMS "
            f"({fmt(learning['tracking_rms_pct_of_range'])} % of the range; the causal floor of the ramped reference "
            f"{fmt(learning['causal_floor_N'])} N).")
    return {"text": text, "rows": rows}


def _provenance(study: ReportStudy, records: dict[str, dict[str, Any]], ff_doc: dict[str, Any], src_text: str,
                gain_set: GainSet, now: _dt.datetime) -> dict[str, Any]:
    artifacts = [[o["path"], o["sha256"][:24]] for name in STAGES_READ
                 for o in records.get(name, {}).get("outputs", {}).values()]
    version = package_version()
    rows = [
        ["package", f"piezopreload {version}"],
        ["study file", study.source],
        ["study SHA-256", study.sha256],
        ["feedforward data", src_text],
        ["feedforward data SHA-256", ff_doc["inputs"]["data"]["sha256"]],
        ["gain set SHA-256", gain_set.content_sha256],
        ["report date (UTC)", now.strftime("%Y-%m-%d %H:%M:%S")],
        ["stage times", ", ".join(f"{n} {records[n]['seconds']:.1f} s" for n in records
                                  if records[n].get("status") == "done" and "seconds" in records[n])],
    ]
    return {"package_version": version, "date": now.strftime("%Y-%m-%d"), "rows": rows, "artifacts": artifacts}


def signal_name(signal: str) -> str:
    return {"measured_N": "measured force", "force_N": "true force"}.get(signal, signal)

