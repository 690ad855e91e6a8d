"""The tuning step of a study: tune, compare, bound, validate, and write the gain set."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from piezopreload.core.artifacts import write_artifact
from piezopreload.core.errors import InputError
from piezopreload.models.actuator import Rig, RigParams
from piezopreload.models.closedloop import Reference
from piezopreload.models.controller import PIDGains
from piezopreload.models.hysteresis import ClassicalPI, model_from_dict
from piezopreload.pipeline import finite_or_none, gains_from_dict, gains_to_dict, load_gains
from piezopreload.study import Study
from piezopreload.tuning.calibrate import PAPER_RESULTS, identify_feedforward
from piezopreload.tuning.pid import TuningInfeasible, TuningSpec, minimum_time, tracking_floor, tune_pid
from piezopreload.tuning.validate import Criteria, SchedulerError, ValidationResult, evaluate, executor, validate

__all__ = ["tune_study", "tune_gains", "validate_tuned", "tune_summary", "compare_gains", "validate_gain_set"]


def compare_gains(study: Study, candidates: dict[str, PIDGains], feedforward: ClassicalPI,
                  criteria: Criteria, seed: int) -> list[dict[str, Any]]:
    """Each gain set without and with the feedforward on the study's nominal rig: one row each."""
    rows = []
    for name, gains in candidates.items():
        for ff in (False, True):
            m = evaluate(gains, feedforward if ff else None, study.rig, study.references["step"],
                         study.references["trajectory"], criteria, seed)
            rows.append({
                "gains": name, "feedforward": ff,
                "rise_s": finite_or_none(m["rise_s"][0]), "settling_s": finite_or_none(m["settling_s"][0]),
                "settling_measured_s": finite_or_none(m["settling_measured_s"][0]),
                "overshoot_N": float(m["overshoot_N"][0]), "tracking_rms_N": float(m["tracking_rms_all_N"][0]),
                "tracking_rms_after_change_N": float(m["tracking_rms_N"][0]),
                "peak_command_V": float(m["peak_voltage_V"][0]),
            })
    return rows


def tune_gains(
    study: Study,
    feedforward: ClassicalPI,
    *,
    seed: int | None = None,
    spec: TuningSpec | None = None,
    criteria: Criteria | None = None,
    progress: Callable[[str], None] | None = None,
    iterations: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """Tune the PID around the study's rig compensated by ``feedforward``; compare and bound it.

    Returns the body of a ``tuning`` artifact: the tuned gains and the SIMC baseline, the
    table of the paper's, SIMC's and the tuned gains on the nominal rig with and without the
    feedforward, the minimum-time bound and the tracking floor. No Monte Carlo: that is
    :func:`validate_tuned`. ``iterations`` gets the IPOPT iteration count as the tuning goes.
    """
    say = progress or (lambda msg: print(msg, file=sys.stderr, flush=True))
    seed = study.seed if seed is None else seed
    criteria = criteria or study.criteria
    spec = spec or study.tuning_spec
    say("tuning the PID around the compensated plant (CasADi + IPOPT) ...")
    try:
        tuning = tune_pid(study.rig, feedforward.inverse(), spec, progress=iterations)
    except TuningInfeasible as exc:
        raise InputError(f"{study.path}: {exc}") from None
    say(f"  tuned in {tuning.seconds:.0f} s: Kc {tuning.gains.Kc:.4g} V/N, Ti {tuning.gains.Ti_s:.4g} s, "
        f"Td {tuning.gains.Td_s:.4g} s, Tf {tuning.gains.Tf_s:.4g} s, b {tuning.gains.b:.3g}")
    say("the lower bound: minimum-time step (optimal control) ...")
    bound = minimum_time(study.rig, initial_N=float(study.references["step"].levels_N[0]),
                         final_N=float(study.references["step"].levels_N[1]), band_N=study.band_N,
                         u_min_V=spec.u_min_V, u_max_V=spec.u_max_V)
    floor = tracking_floor(study.rig, study.references["trajectory"])
    say("comparing the paper's, the SIMC and the tuned gains on the nominal rig ...")
    table = compare_gains(study, {"paper": study.gains, "simc": tuning.baseline, "tuned": tuning.gains},
                          feedforward, criteria, seed)
    tuned_row = next(r for r in table if r["gains"] == "tuned" and r["feedforward"])
    settle = tuned_row["settling_s"]
    return {
        "gains": gains_to_dict(tuning.gains),
        "simc_baseline": gains_to_dict(tuning.baseline),
        "tuning": {**tuning.to_dict(), "spec": _spec_dict(spec)},
        # how the table was scored (the validation's limits are the validate step's)
        "criteria": {k: v for k, v in criteria.to_dict().items() if k in ("band_N", "signal", "tracking_after_change_s")},
        "table": table,
        "paper": {"ff+pid": PAPER_RESULTS["ff+pid"]},
        "minimum_time": {"settling_s": bound["settling_s"],
                         "tuned_over_bound_ratio": None if settle is None else settle / bound["settling_s"]},
        "tracking_floor": {**floor, "tuned_over_floor_ratio": tuned_row["tracking_rms_N"] / floor["rms_N"]},
        "tracking_improvement": _improvement(table),
        "inputs": {"study": study.path, "study_sha256": study.sha256, "seed": seed},
    }


def validate_tuned(
    study: Study,
    tuned: dict[str, Any],
    feedforward: ClassicalPI,
    feedforward_info: dict[str, Any],
    *,
    out: str | Path,
    n_plants: int | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    seed: int | None = None,
    criteria: Criteria | None = None,
    inputs: dict[str, Any] | None = None,
    progress: Callable[[str], None] | None = None,
    bar: Callable[[int, int], None] | None = None,
) -> tuple[dict[str, Any], ValidationResult]:
    """Validate tuned gains (a :func:`tune_gains` body) by Monte Carlo; write the gain set to ``out``.

    The gain set is "validated" only if every plant met every criterion; otherwise it is
    written as a "candidate" (which export and push refuse). Returns the document written
    and the per-plant result.
    """
    say = progress or (lambda msg: print(msg, file=sys.stderr, flush=True))
    n_plants = study.validation_plants if n_plants is None else n_plants
    if n_plants < 1:
        raise InputError(f"--plants: must be >= 1, got {n_plants}")
    seed = study.validation_seed if seed is None else seed
    gains = gains_from_dict(tuned["gains"], "the tuning")
    criteria = criteria or study.criteria
    say(f"validating on {n_plants} plants ...")
    result = _monte_carlo(gains, feedforward, study.rig, criteria, n_plants, seed, study.references["step"],
                          study.references["trajectory"], workers, scheduler, say, bar)
    body = {
        "status": "validated" if result.passed else "candidate",
        "gains": tuned["gains"],
        "feedforward": {"model": feedforward.to_dict(), "units": {"input": "V", "output": "N"},
                        "identification": feedforward_info},
        "plant": {"preset": study.name, "rig": study.rig.to_dict()},
        "criteria": criteria.to_dict(),
        "references": {name: _reference_dict(study.references[name]) for name in ("step", "trajectory")},
        "validation": result.to_dict(),
        "tuning": {**tuned["tuning"], "simc_baseline": tuned["simc_baseline"]},
        "inputs": {"study": study.path, "study_sha256": study.sha256, "seed": seed, **(inputs or {})},
    }
    return write_artifact(out, "gain-set", body), result


def tune_study(
    study: Study,
    *,
    out: str | Path,
    n_plants: int | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    seed: int | None = None,
    spec: TuningSpec | None = None,
    criteria: Criteria | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Identify the feedforward, tune, validate by Monte Carlo and write the gain set to ``out``."""
    say = progress or (lambda msg: print(msg, file=sys.stderr, flush=True))
    t0 = time.perf_counter()
    if n_plants is not None and n_plants < 1:
        raise InputError(f"--plants: must be >= 1, got {n_plants}")
    say("identifying the feedforward on a simulated loop measurement ...")
    feedforward, info = identify_feedforward(Rig(study.rig), study.excitation)
    tuned = tune_gains(study, feedforward, seed=seed, spec=spec, criteria=criteria, progress=say)
    ff_info = {"source": "simulated loop measurement", "excitation": asdict(study.excitation), "fit": info["fit"]}
    doc, result = validate_tuned(study, tuned, feedforward, ff_info, out=out, n_plants=n_plants, criteria=criteria,
                                 workers=workers or study.validation_workers, scheduler=scheduler,
                                 seed=study.validation_seed if seed is None else seed, progress=say)
    return tune_summary(tuned, doc, str(out), time.perf_counter() - t0)


def tune_summary(tuned: dict[str, Any], doc: dict[str, Any], out: str, seconds: float) -> dict[str, Any]:
    """What ``piezopreload tune`` prints: the tuned row with the feedforward as the headline."""
    table = tuned["table"]
    tuned_row = next(r for r in table if r["gains"] == "tuned" and r["feedforward"])
    paper_row = next(r for r in table if r["gains"] == "paper" and r["feedforward"])
    return {
        "settling_s": tuned_row["settling_s"], "settling_measured_s": tuned_row["settling_measured_s"],
        "overshoot_N": tuned_row["overshoot_N"], "tracking_rms_N": tuned_row["tracking_rms_N"],
        "tracking_rms_after_change_N": tuned_row["tracking_rms_after_change_N"],
        "paper_tracking_rms_N": paper_row["tracking_rms_N"],
        "paper_tracking_rms_after_change_N": paper_row["tracking_rms_after_change_N"],
        "lower_bound_settling_s": tuned["minimum_time"]["settling_s"],
        "lower_bound_tracking_rms_N": tuned["tracking_floor"]["rms_N"],
        "out": out, "status": doc["status"], "content_sha256": doc["content_sha256"],
        "gains": tuned["gains"], "simc": tuned["simc_baseline"],
        "tuning": {k: v for k, v in tuned["tuning"].items() if k != "spec"}, "table": table,
        "paper": tuned["paper"], "minimum_time": tuned["minimum_time"],
        "tracking_improvement": tuned["tracking_improvement"], "tracking_floor": tuned["tracking_floor"],
        "validation": doc["validation"], "seconds": seconds,
    }


def _monte_carlo(gains: PIDGains, feedforward: ClassicalPI | None, plant: RigParams, criteria: Criteria,
                 n_plants: int, seed: int, step: Reference, trajectory: Reference, workers: int | None,
                 scheduler: str | None, say: Callable[[str], None],
                 bar: Callable[[int, int], None] | None = None) -> ValidationResult:
    """:func:`validate` on the executor the user asked for, its progress shown per chunk (or on ``bar``)."""
    try:
        with executor(workers, scheduler) as (pool, pool_name):
            return validate(gains, feedforward, plant, criteria, n_plants=n_plants, seed=seed, step=step,
                            trajectory=trajectory, pool=pool, pool_name=pool_name,
                            progress=bar or (lambda i, n: say(f"  chunk {i}/{n}")))
    except SchedulerError as exc:
        raise InputError(f"--scheduler: {exc}") from None


def _reference_dict(ref: Reference) -> dict[str, Any]:
    return {"times_s": ref.times_s.tolist(), "levels_N": ref.levels_N.tolist(), "duration_s": ref.duration_s}


def _reference_from(path: str | Path, doc: dict[str, Any], name: str) -> Reference:
    try:
        r = doc["references"][name]
        return Reference(np.asarray(r["times_s"], float), np.asarray(r["levels_N"], float), float(r["duration_s"]))
    except (KeyError, TypeError, ValueError) as exc:
        detail = f"missing {exc}" if isinstance(exc, KeyError) else str(exc)
        raise InputError(f"{path}: field 'references.{name}' is not a reference ({detail}); "
                         "write the gain set again with 'piezopreload tune'") from None


def validate_gain_set(
    path: str | Path,
    *,
    n_plants: int | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    seed: int | None = None,
    out: str | Path | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Validate a gain set again, on its own plant, feedforward, criteria and references.

    A new Monte Carlo set (``n_plants``, ``seed``: by default the ones stored); with ``out``,
    the gain set is written there with this validation and the status it earns.
    """
    say = progress or (lambda msg: print(msg, file=sys.stderr, flush=True))
    if n_plants is not None and n_plants < 1:
        raise InputError(f"--plants: must be >= 1, got {n_plants}")
    gains, doc = load_gains(path)
    if n_plants is None:
        stored = (doc.get("validation") or {}).get("n_plants")
        n_plants = stored if isinstance(stored, int) and stored >= 1 else 200
    try:
        ff_doc = doc["feedforward"]["model"]
        feedforward = model_from_dict(ff_doc, where="feedforward.model") if ff_doc is not None else None
        plant = RigParams.from_dict(doc["plant"]["rig"])
        criteria = Criteria(**doc["criteria"])
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{path}: field {exc} is missing or invalid; write the gain set again with 'piezopreload tune'") from None
    if feedforward is not None and not isinstance(feedforward, ClassicalPI):
        raise InputError(f"{path}: field 'feedforward.model.kind': validation runs the classical P-I inverse")
    step, trajectory = _reference_from(path, doc, "step"), _reference_from(path, doc, "trajectory")
    seed = int(doc.get("inputs", {}).get("seed", 0)) if seed is None else seed
    say(f"validating {path} on {n_plants} plants ...")
    result = _monte_carlo(gains, feedforward, plant, criteria, n_plants, seed, step, trajectory, workers, scheduler, say)
    summary = result.summary()
    status = "validated" if result.passed else "candidate"
    written = None
    if out is not None:
        body = {k: v for k, v in doc.items() if k not in ("schema", "package_version", "created_utc", "content_sha256")}
        body.update(status=status, validation=result.to_dict(),
                    inputs={**doc.get("inputs", {}), "revalidated_from_sha256": doc["content_sha256"], "seed": seed})
        written = write_artifact(out, "gain-set", body)["content_sha256"]
    return {
        "gains": str(path), "validated": result.passed, "status": status, "plants": n_plants, "seed": seed,
        "worst_settling_s": summary["settling_s"]["worst"], "p95_settling_s": summary["settling_s"]["p95"],
        "worst_overshoot_N": summary["overshoot_N"]["worst"],
        "worst_tracking_rms_N": summary["tracking_rms_N"]["worst"],
        "worst_peak_voltage_V": summary["peak_voltage_V"]["worst"],
        "validation": result.to_dict(), "out": None if out is None else str(out), "content_sha256": written,
    }


def _improvement(table: list[dict[str, Any]]) -> dict[str, float]:
    """The paper's tracking RMS over the tuned one (with feedforward), both ways of scoring it."""
    row = {(r["gains"], r["feedforward"]): r for r in table}
    tuned = row[("tuned", True)]
    out = {}
    for ref in (("paper", False), ("paper", True)):
        key = "paper_pid" if not ref[1] else "paper_ff_pid"
        out[f"{key}_over_tuned"] = row[ref]["tracking_rms_N"] / tuned["tracking_rms_N"]
        out[f"{key}_over_tuned_after_change"] = row[ref]["tracking_rms_after_change_N"] / tuned["tracking_rms_after_change_N"]
    return out


def _spec_dict(spec: TuningSpec) -> dict[str, Any]:
    return {
        "band_N": spec.band_N, "overshoot_margin_N": spec.overshoot_margin_N, "ms_max": spec.ms_max,
        "noise_gain_max_V_per_N": spec.noise_gain_max_V_per_N, "u_min_V": spec.u_min_V, "u_max_V": spec.u_max_V,
        "tune_setpoint_weight": spec.tune_setpoint_weight, "variants": dict(spec.variants),
    }
