"""The one-command study: ``piezopreload run [STUDY.toml] [--out DIR] [--force]``.

A study goes through eight stages, each writing versioned artifacts into the output folder:

==========  ==================================================================  ==========================
stage       what it does                                                        writes
==========  ==================================================================  ==========================
identify    the feedforward's P-I model from the loop measurement (simulated    feedforward/model.json,
            on the rig's truth model, or the study's ``[feedforward] data``)     feedforward/loop.csv
design      ball-screw preload optimum, Pareto fronts, preload schedule          design/design.json + CSVs
tune        PID gains around the compensated plant (CasADi), compared, bounded  tuning.json
validate    the tuned gains on a Monte Carlo set of nonlinear rigs              gains.json, validation.json
compare     step and trajectory, paper's and tuned gains, with/without FF       responses/
export      the validated gain set in the study's controller formats            exports/
rig         the validated gains on the rig executor (simulated by default)      runs/run-*.csv + .json
report      figures and the PDF (Typst)                                          report/, report.pdf
==========  ==================================================================  ==========================

Every stage has a key: the SHA-256 of its study tables, the hashes of the artifacts it reads
and the hash of the code it runs. ``pipeline.json`` records each stage's key and the hashes of
what it wrote; a stage whose key and outputs are unchanged is not run again, so a second run
of a study only checks hashes. ``--force`` reruns everything. A failing stage stops the study
with its name; what the stages before it wrote stays, and the manifest records the failure.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from piezopreload import __version__
from piezopreload.core.artifacts import (
    ArtifactError,
    atomic_write_bytes,
    atomic_write_text,
    read_artifact,
    write_artifact,
)
from piezopreload.core.errors import InputError
from piezopreload.core.tables import read_record
from piezopreload.models.actuator import Rig
from piezopreload.models.closedloop import ClosedLoopRun, simulate, simulate_open_loop, triangle
from piezopreload.models.controller import Controller
from piezopreload.models.hysteresis import ClassicalPI
from piezopreload.pipeline import (
    finite_or_none,
    gains_from_dict,
    load_hysteresis_model,
    step_numbers,
    write_csv,
    write_run_csv,
)
from piezopreload.progress import Progress
from piezopreload.study import Study, StudyText, default_study, load_study, read_study_text
from piezopreload.tuning.calibrate import PAPER_RESULTS, fit_feedforward, identify_feedforward

__all__ = ["STAGES", "StageFailed", "run_study", "rerender_report", "read_manifest", "DEFAULT_OUT"]

DEFAULT_OUT = "piezopreload-out"
MANIFEST = "pipeline.json"
STUDY_COPY = "study.toml"
#: the exit code of a study whose rig run an interlock stopped (as ``rig run``)
EXIT_TRIPPED = 3


class StageFailed(InputError):
    """A stage that could not complete: the message names it; ``exit_code`` is what the CLI returns."""

    def __init__(self, stage: str, message: str, exit_code: int = 2) -> None:
        super().__init__(f"stage '{stage}' failed: {message}")
        self.stage = stage
        self.exit_code = exit_code


class StageCrashed(RuntimeError):
    """An internal failure inside a stage (exit code 1); the cause is chained."""


# --------------------------------------------------------------------------------------
# hashing
# --------------------------------------------------------------------------------------
def _sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _canonical(value: Any) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), default=str)


_CODE_HASHES: dict[str, str] = {}


def _code_hash(packages: tuple[str, ...]) -> str:
    """SHA-256 of the source (``.py``, ``.typ``) of ``piezopreload`` and the named subpackages."""
    key = ",".join(packages)
    if key not in _CODE_HASHES:
        h = hashlib.sha256()
        for name in ("piezopreload",) + tuple(f"piezopreload.{p}" for p in packages):
            root = Path(importlib.import_module(name).__file__).parent
            for path in sorted(p for p in root.rglob("*") if p.suffix in (".py", ".typ") and "__pycache__" not in p.parts):
                h.update(f"{name}/{path.relative_to(root).as_posix()}\n".encode())
                h.update(path.read_bytes())
        _CODE_HASHES[key] = h.hexdigest()
    return _CODE_HASHES[key]


# --------------------------------------------------------------------------------------
# the stages
# --------------------------------------------------------------------------------------
@dataclass
class _Ctx:
    study: Study
    text: StudyText
    out: Path
    progress: Progress
    records: dict[str, dict[str, Any]]
    source: str = ""                         # the study file as the user named it
    template: str | None = None              # a Typst template's text to use instead of the shipped one

    def output(self, stage: str, label: str) -> Path:
        return self.out / self.records[stage]["outputs"][label]["path"]

    def rel(self, path: Path) -> str:
        return Path(path).resolve().relative_to(self.out.resolve()).as_posix()


@dataclass(frozen=True)
class Stage:
    name: str
    what: str
    tables: tuple[str, ...]                 # the study tables its key covers
    needs: tuple[str, ...]                  # upstream stages whose outputs it reads
    code: tuple[str, ...]                   # subpackages whose source its key covers
    run: Callable[[_Ctx], tuple[dict[str, Path], dict[str, Any]]]
    files: Callable[[Study], list[str]] = lambda study: []   # input files outside the study (hashed)
    applies: Callable[[Study], str | None] = lambda study: None  # a reason it does not apply, or None


def _ff_files(study: Study) -> list[str]:
    return [study.feedforward_data] if study.feedforward_data else []


def _stage_identify(ctx: _Ctx) -> tuple[dict[str, Path], dict[str, Any]]:
    study, say = ctx.study, ctx.progress.say
    rig = Rig(study.rig)
    if study.feedforward_data is None:
        say(f"simulating the {study.excitation.v_max_V:g} V, {study.excitation.frequency_Hz:g} Hz loop measurement "
            "on the rig's truth model")
        model, info = identify_feedforward(rig, study.excitation)
        rec = info["record"]
        t, v, y = rec["time_s"], rec["command_V"], rec["measured_N"]
        source = {"kind": "simulated", "excitation": asdict(study.excitation)}
    else:
        say(f"reading the measured loop {study.feedforward_data}")
        record = read_record(study.feedforward_data)
        if record.output_unit != "N" or record.input_unit != "V":
            raise InputError(f"{study.feedforward_data}: the feedforward needs a voltage (V) -> force (N) loop; "
                             f"the record has {record.input_name} -> {record.output_name}")
        t, v, y = record.time_s, record.input, record.output
        model, info = fit_feedforward(v, y, study.excitation.n_operators)
        source = {"kind": "measured", "path": study.feedforward_data, "sha256": record.sha256}
    say(f"P-I model: {model.n_operators} operators, fit RMS {info['fit']['rms_pct']:.2f} % "
        f"(max {info['fit']['max_pct']:.2f} %) of the force span")
    # the compensated rig in open loop: a force triangle through the inverse (the paper's Figure 6)
    levels = study.references["trajectory"].levels_N
    lo, hi = float(min(study.references["step"].levels_N.min(), levels.min())), float(levels.max())
    _, desired = triangle(hi - lo, study.excitation.frequency_Hz, 2, rig.dt_s)
    desired = desired + lo
    command = model.inverse()(desired)
    check = simulate_open_loop(rig, command, seed=study.excitation.seed + 1)
    d = ctx.out / "feedforward"
    loop_csv, check_csv = d / "loop.csv", d / "compensation.csv"
    write_csv(loop_csv, {"time_s": t, "voltage_V": v, "force_N": y, "model_N": model(v)},
              f"piezopreload {__version__}: the feedforward's loop measurement ({source['kind']}) and the P-I model's output")
    write_csv(check_csv, {"time_s": check["time_s"], "desired_N": desired, "command_V": command,
                          "force_N": check["force_N"], "measured_N": check["measured_N"]},
              f"piezopreload {__version__}: open loop through the inverse P-I model: desired force, command, the rig's force")
    settle = check["time_s"] >= 1.0 / study.excitation.frequency_Hz  # the first cycle carries the creep's start
    comp_err = (check["force_N"] - desired)[settle]
    comp_rms, comp_max = float(np.sqrt(np.mean(comp_err ** 2))), float(np.max(np.abs(comp_err)))
    data_sha = source.get("sha256") or _sha256_file(loop_csv)
    write_artifact(d / "model.json", "hysteresis-model", {
        "inputs": {"data": {**source, "sha256": data_sha}, "study_sha256": study.sha256},
        "units": {"input": "V", "output": "N", "input_name": "voltage_V", "output_name": "force_N"},
        "model": model.to_dict(),
        "identification": {"fit": info["fit"], "solver_status": info["status"],
                           "compensation_rms_N": comp_rms, "compensation_max_N": comp_max},
    })
    summary = {"source": source["kind"], "data_sha256": data_sha, "operators": model.n_operators,
               "fit_rms_pct": info["fit"]["rms_pct"], "fit_max_pct": info["fit"]["max_pct"],
               "compensation_rms_N": comp_rms}
    return {"model": d / "model.json", "loop": loop_csv, "compensation": check_csv}, summary


def _feedforward(ctx: _Ctx) -> tuple[ClassicalPI, dict[str, Any]]:
    path = ctx.output("identify", "model")
    model, doc = load_hysteresis_model(path)
    if not isinstance(model, ClassicalPI):
        raise ArtifactError(f"{path}: field 'model.kind': the feedforward is a classical P-I model")
    info = {"source": doc["inputs"]["data"], "fit": doc["identification"]["fit"],
            "model_sha256": ctx.records["identify"]["outputs"]["model"]["sha256"]}
    return model, info


def _design_applies(study: Study) -> str | None:
    return None if "ballscrew" in study.raw else "the study has no [ballscrew] table"


def _design_files(study: Study) -> list[str]:
    profile = study.raw.get("schedule", {}).get("profile")
    return [str(Path(study.path).parent / profile)] if profile else []


def _stage_design(ctx: _Ctx) -> tuple[dict[str, Path], dict[str, Any]]:
    from piezopreload.design_pipeline import design_study

    d = ctx.out / "design"
    for stale in d.glob("design.pareto-*.csv"):  # a front the study no longer asks for
        stale.unlink()
    result = design_study(ctx.study.path, out=d / "design.json", progress=ctx.progress.say,
                          bar=ctx.progress.bar("Pareto fronts"))
    outputs = {"design": d / "design.json"}
    for path in result["written"][1:]:
        outputs[Path(path).stem.rpartition(".")[2]] = Path(path)
    p = result["optimum"]
    summary = {"objective": result["objective"], "stiffness_N_per_um": p["stiffness_N_per_um"],
               "binding": result["binding"], "fronts": [f["pair"] for f in result["fronts"]],
               "schedule_saving_fraction": result["schedule"]["saving_fraction"]}
    return outputs, summary


def _stage_tune(ctx: _Ctx) -> tuple[dict[str, Path], dict[str, Any]]:
    from piezopreload.tuning_pipeline import tune_gains

    feedforward, _ = _feedforward(ctx)
    tuned = tune_gains(ctx.study, feedforward, progress=lambda m: ctx.progress.say(m.strip()),
                       iterations=ctx.progress.counter("IPOPT iterations", every=10))
    tuned["inputs"]["feedforward_sha256"] = ctx.records["identify"]["outputs"]["model"]["sha256"]
    path = ctx.out / "tuning.json"
    write_artifact(path, "tuning", tuned)
    g = tuned["gains"]
    return {"tuning": path}, {"Kc_V_per_N": g["Kc_V_per_N"], "Ti_s": g["Ti_s"], "Td_s": g["Td_s"],
                              "Tf_s": g["Tf_s"], "b": g["b"], "ms": tuned["tuning"]["ms"]}


def _stage_validate(ctx: _Ctx) -> tuple[dict[str, Path], dict[str, Any]]:
    from piezopreload.tuning_pipeline import validate_tuned

    study = ctx.study
    feedforward, ff_info = _feedforward(ctx)
    tuned = read_artifact(ctx.output("tune", "tuning"), "tuning")
    gains_path, validation_path = ctx.out / "gains.json", ctx.out / "validation.json"
    doc, result = validate_tuned(
        study, tuned, feedforward, ff_info, out=gains_path, workers=study.validation_workers,
        inputs={"tuning_sha256": ctx.records["tune"]["outputs"]["tuning"]["sha256"]},
        progress=ctx.progress.say, bar=ctx.progress.bar(f"Monte Carlo, {study.validation_plants} plants"))
    write_artifact(validation_path, "validation", {
        "gain_set_sha256": doc["content_sha256"], "passed": result.passed, "n_plants": result.n_plants,
        "seed": result.seed, "criteria": result.criteria.to_dict(), "spread": result.spread,
        "metrics": {k: [finite_or_none(x) for x in v] for k, v in result.metrics.items()},
        "summary": result.summary(), "failures": result.failures, "seconds": result.seconds,
        "inputs": {"gain_set": "gains.json", "study_sha256": study.sha256},
    })
    outputs = {"gains": gains_path, "validation": validation_path}
    if not result.passed:
        worst = "; ".join(f"plant {f['plant']}: {f['metric']} {f['value']} > {f['limit']:g}" for f in result.failures[:3])
        raise StageFailed("validate", f"the tuned gains failed on {len({f['plant'] for f in result.failures})} of "
                                      f"{result.n_plants} plants ({worst}); {gains_path} is a candidate, which export "
                                      "and the rig refuse. Loosen the [validation] limits or tighten [tuning] "
                                      "(ms_max, overshoot_margin_N) and run again", exit_code=2) from _Partial(outputs)
    s = result.summary()
    return outputs, {"status": doc["status"], "content_sha256": doc["content_sha256"], "plants": result.n_plants,
                     "worst_settling_s": s["settling_s"]["worst"], "worst_overshoot_N": s["overshoot_N"]["worst"]}


class _Partial(Exception):
    """Carries what a failing stage wrote, so the manifest can list it."""

    def __init__(self, outputs: dict[str, Path]) -> None:
        super().__init__("partial outputs")
        self.outputs = outputs


_RESPONSE_GAINS = ("paper", "tuned")
_RESPONSE_CONTROLLERS = ("pid", "ff+pid")
_RESPONSE_REFERENCES = ("step", "trajectory")


def _stage_compare(ctx: _Ctx) -> tuple[dict[str, Path], dict[str, Any]]:
    study = ctx.study
    feedforward, _ = _feedforward(ctx)
    gains_doc = read_artifact(ctx.output("validate", "gains"), "gain-set")
    candidates = {"paper": study.gains, "tuned": gains_from_dict(gains_doc["gains"], ctx.output("validate", "gains"))}
    rig = Rig(study.rig)
    d = ctx.out / "responses"
    outputs: dict[str, Path] = {}
    runs: list[dict[str, Any]] = []
    bar = ctx.progress.bar("closed-loop runs")
    total = len(_RESPONSE_GAINS) * len(_RESPONSE_CONTROLLERS) * len(_RESPONSE_REFERENCES)
    for name in _RESPONSE_GAINS:
        for controller in _RESPONSE_CONTROLLERS:
            for ref_name in _RESPONSE_REFERENCES:
                ff = feedforward.inverse() if controller == "ff+pid" else None
                run = simulate(rig, Controller(candidates[name], rig.dt_s, ff), study.references[ref_name], seed=study.seed)
                label = f"{name}-{controller.replace('+', '-')}-{ref_name}"
                path = d / f"{label}.csv"
                write_run_csv(path, run, f"piezopreload {__version__} run: study {study.name}, {name} gains, "
                                         f"{controller}, {ref_name}, seed {study.seed}")
                outputs[label] = path
                runs.append({"gains": name, "controller": controller, "reference": ref_name, "csv": ctx.rel(path),
                             **_run_metrics(run, study)})
                bar(len(runs), total)
    rows = []
    for controller in _RESPONSE_CONTROLLERS:
        for metric in ("rise_s", "peak_s", "settling_s"):
            got = {r["gains"]: r[metric] for r in runs if r["controller"] == controller and r["reference"] == "step"}
            rows.append({"controller": controller, "metric": metric, "paper": PAPER_RESULTS[controller][metric],
                         "reproduction": got["paper"], "tuned": got["tuned"]})
    write_artifact(d / "responses.json", "responses", {
        "runs": runs, "reproduction": rows, "band_N": study.band_N, "signal": study.signal, "seed": study.seed,
        "inputs": {"gain_set_sha256": gains_doc["content_sha256"], "study_sha256": study.sha256,
                   "feedforward_sha256": ctx.records["identify"]["outputs"]["model"]["sha256"]},
    })
    outputs["responses"] = d / "responses.json"
    return outputs, {"reproduction": rows}


def _run_metrics(run: ClosedLoopRun, study: Study) -> dict[str, Any]:
    out: dict[str, Any] = {**step_numbers(run, study), "peak_command_V": float(np.max(run.command_V))}
    te = run.tracking_error()
    after = run.tracking_error(after_change_s=study.criteria.tracking_after_change_s)
    out.update(tracking_rms_N=float(te["rms"]), tracking_max_N=float(te["max"]),
               tracking_rms_after_change_N=float(after["rms"]))
    return out


_EXTENSIONS = {"json": "gains.si.json", "labview": "gains.labview.txt", "plc": "gains.plc.txt",
               "c-header": "pp_gains.h", "casadi-c": "pp_controller.c"}


def _stage_export(ctx: _Ctx) -> tuple[dict[str, Path], dict[str, Any]]:
    from piezopreload.rig.export import ExportError, export_text

    gains_path = ctx.output("validate", "gains")
    doc = read_artifact(gains_path, "gain-set")
    outputs = {}
    for fmt in ctx.study.export_formats:
        try:
            text = export_text(doc, fmt)
        except ExportError as exc:
            raise InputError(f"{gains_path}: {exc}") from None
        path = ctx.out / "exports" / _EXTENSIONS[fmt]
        atomic_write_text(path, text)
        outputs[fmt] = path
        ctx.progress.say(f"{fmt}: {ctx.rel(path)}")
    return outputs, {"formats": list(ctx.study.export_formats)}


def _rig_files(study: Study) -> list[str]:
    ref = study.rig_run.reference
    return [ref] if ref.lower().endswith(".csv") else []


def _stage_rig(ctx: _Ctx) -> tuple[dict[str, Path], dict[str, Any]]:
    from piezopreload.rig_pipeline import run_rig

    plan = ctx.study.rig_run
    ctx.progress.say(f"backend '{plan.backend}', reference {Path(plan.reference).name}, "
                     f"{'real time' if plan.realtime else 'back to back'}")
    s = run_rig(ctx.output("validate", "gains"), backend=plan.backend, reference=plan.reference,
                realtime=plan.realtime, log_dir=ctx.out / "runs", safety=plan.safety(), seed=plan.seed)
    outputs = {"log_csv": Path(s["log_csv"]), "log_json": Path(s["log_json"])}
    m = s["metrics"]
    summary = {"status": s["status"], "cycles": s["cycles"], "controller_step": s["controller_step"],
               "settling_s": m.get("settling_s"), "overshoot_N": m.get("overshoot_N"),
               "tracking_rms_N": m.get("tracking_rms_N"), "missed_deadlines": s["timing"].get("missed_deadlines")}
    if s["exit_code"] != 0:
        trip = s["trip"] or {}
        raise StageFailed("rig", f"the run was stopped by the interlock '{trip.get('cause')}' at "
                                 f"t = {trip.get('t_s', float('nan')):.3f} s: {trip.get('detail')}; "
                                 f"the log is {s['log_csv']}", exit_code=EXIT_TRIPPED) from _Partial(outputs)
    ctx.progress.say(f"{s['status']}: {s['cycles']} cycles; log {ctx.rel(Path(s['log_csv']))}")
    return outputs, summary


def _stage_report(ctx: _Ctx) -> tuple[dict[str, Path], dict[str, Any]]:
    from piezopreload.reports.study_report import ReportStudy, render_report

    study, raw = ctx.study, ctx.study.raw
    b = raw.get("ballscrew")
    facts = ReportStudy(study.name, study.title, study.path, study.sha256, ctx.source or study.path,
                        None if b is None else (b.get("nominal_diameter_mm"), b.get("lead_mm")),
                        raw.get("design", {}).get("frequency_min_Hz"))
    return render_report(ctx.out, ctx.records, facts, say=ctx.progress.say, bar=ctx.progress.bar("figures"),
                         template=ctx.template)


_STUDY_TABLES = ("study",)
STAGES: tuple[Stage, ...] = (
    Stage("identify", "the feedforward's P-I model", ("rig", "feedforward", "reference"), (), ("models", "tuning"),
          _stage_identify, files=_ff_files),
    Stage("design", "ball-screw preload design, Pareto fronts, schedule",
          ("ballscrew", "feed_drive", "duty", "design", "schedule"), (), ("models", "design"), _stage_design,
          files=_design_files, applies=_design_applies),
    Stage("tune", "PID gains around the compensated plant (CasADi + IPOPT)",
          ("rig", "controller", "reference", "simulation", "tuning"), ("identify",),
          ("models", "tuning"), _stage_tune),
    Stage("validate", "Monte Carlo on nonlinear rigs", ("study", "rig", "reference", "simulation", "validation"),
          ("identify", "tune"), ("models", "tuning"), _stage_validate),
    Stage("compare", "step and trajectory: paper's and tuned gains, with and without feedforward",
          ("study", "rig", "controller", "reference", "simulation"), ("identify", "validate"), ("models",),
          _stage_compare),
    Stage("export", "the gain set in the controllers' formats", ("export",), ("validate",), ("models", "rig"),
          _stage_export),
    Stage("rig", "the validated gains on the rig executor", ("rig_run",), ("validate",), ("models", "rig"),
          _stage_rig, files=_rig_files),
    Stage("report", "figures and the PDF", ("study",), ("identify", "design", "tune", "validate", "compare",
                                                           "export", "rig"), ("models", "reports"), _stage_report),
)
_BY_NAME = {s.name: s for s in STAGES}


def _stage_key(stage: Stage, study: Study, records: dict[str, dict[str, Any]]) -> str:
    upstream = {}
    for name in stage.needs:
        rec = records.get(name, {})
        upstream[name] = {label: o["sha256"] for label, o in rec.get("outputs", {}).items()} if rec.get("status") == "done" \
            else rec.get("status")
    files = {}
    for f in stage.files(study):
        try:
            files[f] = _sha256_file(Path(f))
        except OSError as exc:
            raise InputError(f"{study.path}: cannot read {f} ({exc.strerror or exc})") from None
    body = {"stage": stage.name, "version": __version__, "code": _code_hash(stage.code),
            "tables": {t: study.raw.get(t) for t in stage.tables}, "upstream": upstream, "files": files}
    return hashlib.sha256(_canonical(body).encode()).hexdigest()


def _outputs_intact(out: Path, record: dict[str, Any]) -> bool:
    for o in record.get("outputs", {}).values():
        path = out / o["path"]
        if not path.is_file() or _sha256_file(path) != o["sha256"]:
            return False
    return True


# --------------------------------------------------------------------------------------
# the manifest and the lock
# --------------------------------------------------------------------------------------
def read_manifest(out: str | Path) -> dict[str, Any]:
    """The output folder's ``pipeline.json`` (an artifact of kind ``study-run``)."""
    return read_artifact(Path(out) / MANIFEST, "study-run")


def _write_manifest(out: Path, study: Study, records: dict[str, dict[str, Any]], started: str, source: str) -> None:
    write_artifact(out / MANIFEST, "study-run", {
        "study": {"path": source, "sha256": study.sha256, "name": study.name, "copy": STUDY_COPY},
        "started_utc": started,
        "stages": {name: records[name] for name in _BY_NAME if name in records},
    })


@contextmanager
def _locked(out: Path) -> Iterator[None]:
    """One run at a time per output folder (advisory lock; where flock exists)."""
    out.mkdir(parents=True, exist_ok=True)
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    with open(out / ".lock", "w") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise InputError(f"{out}: another 'piezopreload run' or 'report' is writing this folder; "
                             "wait for it or give another --out") from None
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _utc() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


# --------------------------------------------------------------------------------------
# running
# --------------------------------------------------------------------------------------
def _load(path: str | Path | None) -> tuple[Study, StudyText]:
    from piezopreload.design_pipeline import design_spec_from_study

    path = default_study() if path is None else Path(path)
    study = load_study(path)
    text = read_study_text(path)
    if "ballscrew" in text.data:
        design_spec_from_study(text)  # every design table checked on load, before any stage runs
    named = {"feedforward.data": _ff_files(study), "schedule.profile": _design_files(study),
             "rig_run.reference": _rig_files(study)}
    for key, files in named.items():
        for f in files:
            if not Path(f).is_file():
                raise text.fail(key, f"names {f}, which is not a file; give a path relative to the study file")
    return study, text


def _execute(stages: list[Stage], study: Study, text: StudyText, out: Path, force: bool,
             progress: Progress, previous: dict[str, dict[str, Any]], started: str, source: str,
             template: str | None = None) -> list[dict[str, Any]]:
    records = dict(previous)
    done: list[dict[str, Any]] = []
    ctx = _Ctx(study, text, out, progress, records, source, template)
    for i, stage in enumerate(stages, start=1):
        reason = stage.applies(study)
        key = _stage_key(stage, study, records)
        old = records.get(stage.name)
        if reason is not None:
            progress.stage(i, len(stages), stage.name, f"not applicable ({reason})")
            records[stage.name] = {"status": "not applicable", "reason": reason, "key": key, "outputs": {}}
            done.append({"stage": stage.name, "ran": False, "status": "not applicable", "seconds": 0.0})
            continue
        if not force and old is not None and old.get("status") == "done" and old.get("key") == key \
                and _outputs_intact(out, old):
            progress.stage(i, len(stages), stage.name, "up to date, not run again")
            done.append({"stage": stage.name, "ran": False, "status": "up to date", "seconds": 0.0,
                         "outputs": {k: o["path"] for k, o in old["outputs"].items()}})
            continue
        progress.stage(i, len(stages), stage.name, stage.what)
        t0 = time.perf_counter()
        try:
            outputs, summary = stage.run(ctx)
        except Exception as exc:
            partial = exc.__cause__.outputs if isinstance(exc.__cause__, _Partial) else {}
            message = str(exc) if isinstance(exc, InputError) else f"{type(exc).__name__}: {exc}"
            records[stage.name] = {
                "status": "failed", "key": key, "message": message, "seconds": time.perf_counter() - t0,
                "finished_utc": _utc(),
                "outputs": {label: {"path": ctx.rel(p), "sha256": _sha256_file(p)} for label, p in partial.items()
                            if p.is_file()},
            }
            _write_manifest(out, study, records, started, source)
            if isinstance(exc, StageFailed):
                raise
            if isinstance(exc, InputError):
                raise StageFailed(stage.name, str(exc)) from exc
            raise StageCrashed(f"stage '{stage.name}' failed: {type(exc).__name__}: {exc}") from exc
        seconds = time.perf_counter() - t0
        records[stage.name] = {
            "status": "done", "key": key, "seconds": seconds, "finished_utc": _utc(), "summary": summary,
            "outputs": {label: {"path": ctx.rel(p), "sha256": _sha256_file(p)} for label, p in outputs.items()},
        }
        _write_manifest(out, study, records, started, source)
        progress.say(f"done in {seconds:.1f} s")
        done.append({"stage": stage.name, "ran": True, "status": "done", "seconds": seconds,
                     "outputs": {k: o["path"] for k, o in records[stage.name]["outputs"].items()}})
    return done


def _previous(out: Path, progress: Progress) -> dict[str, dict[str, Any]]:
    if not (out / MANIFEST).exists():
        return {}
    try:
        return dict(read_manifest(out)["stages"])
    except InputError as exc:
        progress.say(f"warning: {exc}; every stage runs again")
        return {}


def run_study(path: str | Path | None = None, out: str | Path = DEFAULT_OUT, *, force: bool = False,
              progress: Progress | None = None) -> dict[str, Any]:
    """Run a study's stages into ``out``; a stage whose key and outputs are unchanged is not run again."""
    progress = progress or Progress()
    t0 = time.perf_counter()
    study, text = _load(path)
    out = Path(out)
    with _locked(out):
        raw = Path(study.path).read_bytes()
        copy = out / STUDY_COPY
        if not copy.is_file() or copy.read_bytes() != raw:
            atomic_write_bytes(copy, raw)
        previous = _previous(out, progress)
        stages = _execute(list(STAGES), study, text, out, force, progress, previous, _utc(), study.path)
    ran = [s["stage"] for s in stages if s["ran"]]
    seconds = time.perf_counter() - t0
    progress.write(f"{'ran ' + ', '.join(ran) if ran else 'nothing to run: every stage is up to date'} "
                    f"({seconds:.1f} s)\nthe study's outputs are in {out.resolve()}/ (report: {out / 'report.pdf'})\n")
    return _result(out, study, stages, seconds)


def rerender_report(out: str | Path, progress: Progress | None = None, template: str | Path | None = None) -> dict[str, Any]:
    """Render the report again from the artifacts in ``out`` (``piezopreload report DIR``); nothing else runs.

    ``template``: a Typst file to typeset instead of the shipped template (a copy of
    ``DIR/report/report.typ``, edited); it reads ``report.json`` and ``figures/`` as the shipped one does.
    """
    progress = progress or Progress()
    t0 = time.perf_counter()
    out = Path(out)
    template_text = None
    if template is not None:
        try:
            template_text = Path(template).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise InputError(f"--template {template}: cannot read it ({exc})") from None
    if not (out / MANIFEST).is_file():
        raise InputError(f"{out}: no {MANIFEST}; this is not a study's output folder (run 'piezopreload run' first)")
    manifest = read_manifest(out)
    records = dict(manifest["stages"])
    missing = [name for name in _BY_NAME["report"].needs
               if records.get(name, {}).get("status") not in ("done", "not applicable")]
    if missing:
        raise InputError(f"{out}: the stage(s) {', '.join(missing)} have not completed; "
                         f"run 'piezopreload run {out / STUDY_COPY} --out {out}' first")
    broken = [name for name in _BY_NAME["report"].needs if not _outputs_intact(out, records[name])]
    if broken:
        raise InputError(f"{out}: the outputs of {', '.join(broken)} changed or went missing since they were written; "
                         f"run 'piezopreload run {out / STUDY_COPY} --out {out}' to make them again")
    study = load_study(out / STUDY_COPY)
    with _locked(out):
        stages = _execute([_BY_NAME["report"]], study, read_study_text(out / STUDY_COPY), out, True, progress,
                          records, manifest.get("started_utc", _utc()), manifest["study"].get("path", study.path),
                          template_text)
    seconds = time.perf_counter() - t0
    progress.write(f"the report is {out / 'report.pdf'} ({seconds:.1f} s)\n")
    return _result(out, study, stages, seconds)


def _result(out: Path, study: Study, stages: list[dict[str, Any]], seconds: float) -> dict[str, Any]:
    records = read_manifest(out)["stages"]
    gains = records.get("validate", {}).get("summary", {})
    out = out.resolve()
    return {
        "out": str(out.resolve()), "study": {"path": study.path, "sha256": study.sha256, "name": study.name},
        "stages": stages, "ran": [s["stage"] for s in stages if s["ran"]], "seconds": seconds,
        "report": str(out / "report.pdf") if (out / "report.pdf").is_file() else None,
        "gain_set": str(out / "gains.json") if (out / "gains.json").is_file() else None,
        "gain_set_sha256": gains.get("content_sha256"),
        "rig_log": (str(out / records["rig"]["outputs"]["log_csv"]["path"])
                    if records.get("rig", {}).get("status") == "done" else None),
    }
