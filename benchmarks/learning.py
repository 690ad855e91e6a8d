"""Preview and iterative learning control: the paper's trajectory and the machine axis' schedule (issues 20 and 29).

**The paper's trajectory** (studies/paper2021.toml): its rig, its gains (Kc 0.3 V/N, Ti 0.08 s,
Td 0.001 s) with the identified inverse-P-I feedforward, the trajectory 25 -> 60-80-100-80-60 N
(5 s holds). Measured here, on the true force:

* the peer, in the same run: the paper's gains with the feedforward, no preview, no learning
  (``paper_tracking_rms_N``; outside 0.1 s after jumps ``paper_tracking_rms_after_change_N``);
* the default law (norm-optimal ILC) with preview, stopping when more trials no longer pay (at most
  ``--iterations``): ``tracking_rms_N`` (whole trajectory from the first change, as the floors are
  scored; targets <= 0.75 N and ``over_branch_floor_ratio`` <= 1.2),
  ``tracking_rms_outside_transitions_N`` (from the preview before each jump to 0.1 s after it left
  out; target <= 0.15 N), ``tracking_rms_after_change_N``, ``tracking_rms_from_start_N``,
  ``trials`` (the learning trials it ran) and ``learned_over_paper_ratio``;
* the same law run for every one of ``--iterations`` trials: ``trials_to_within_1p1``, the first trial
  whose error is within 1.1 times the best of them (target <= 2), ``history_rms_N``;
* the P-type law, the model-free option, run for every trial: ``p_type_tracking_rms_N``,
  ``p_type_trials_to_within_1p1``, ``p_type_history_rms_N``;
* the floors: ``preview_floor_N`` (the steepest slope anywhere) and ``preview_floor_branch_N`` (each
  change along the rig's own branch at full slew); ``plan_rms_after_change_N``;
* the default law on ``--plants`` Monte Carlo plants (each its own learning with the nominal law):
  ``mc_converged_fraction`` (converged, by the stopping rule, with an error that never rose by more than
  the noise floor from one trial to the next; target 1.0), ``mc_monotone_fraction``, the worst plant's errors;
* ``trade_off`` (unless ``--no-trade-off``): the learning again with the plan's changes placed to weigh the error
  outside 0.1 s after the jumps ``w`` times more, and ``plan_front``, the plans alone over a sweep of ``w``.

**The machine axis** (studies/machine_axis.toml, ``--machine``): the study is run to its learn stage's
inputs (``piezopreload run`` into a temporary folder, every stage; about a minute), then:

* ``machine_axis_trials_per_pass`` and ``machine_axis_stopped_within_1p1_per_pass``: the learn stage's own
  trials per margin pass (stopping when more no longer pay) and the first trial within 1.1 x each pass's best;
* each pass learned again for every one of 8 trials (a pass warm-started from the last, as the stage does):
  ``machine_axis_trials_to_within_1p1`` (the worst pass; target <= 2) and its history per pass;
* ``norm_optimal_schedule_s_per_trial``: the wall time of one update of the default law on the whole
  schedule (its first, which includes the Riccati recursion; target <= 2 s), beside
  ``norm_optimal_schedule_samples`` and the later updates' ``norm_optimal_schedule_s_per_later_trial``.

The last line printed is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from piezopreload.models.actuator import Rig
from piezopreload.models.closedloop import simulate
from piezopreload.models.controller import Controller
from piezopreload.study import load_study
from piezopreload.tuning.learning import learn, schedule_learner, within_1p1
from piezopreload.tuning.preview import AFTER_CHANGE_S, branch_ramps, feedforward_lead, preview_plan


def plan_front(params, ref, weights, preview_s: float = 0.3) -> list[dict]:
    """The plans' two scores over ``weights``: the least either can be for any placement of the fastest ramps."""
    ramps = branch_ramps(params, ref.levels_N)
    rows = []
    for w in weights:
        plan = preview_plan(params, ref, preview_s, lead_samples=feedforward_lead(params), ramps=ramps,
                            after_change_weight=w)
        t, e = plan.t_s, ref.at(plan.t_s) - plan.force_N
        row = {"after_change_weight": w}
        for name, t_from in (("", ref.times_s[1]), ("_from_start", 0.0)):
            scored = t >= t_from
            outside = scored.copy()
            for tj in ref.times_s[1:]:
                outside &= ~((t >= tj - 1e-12) & (t < tj + AFTER_CHANGE_S - 1e-12))
            row[f"rms_N{name}"] = float(np.sqrt(np.mean(e[scored] ** 2)))
            row[f"rms_after_change_N{name}"] = float(np.sqrt(np.mean(e[outside] ** 2)))
        rows.append(row)
    return rows


def paper(args: argparse.Namespace) -> dict:
    study = load_study("paper2021")
    rig = Rig(study.plant)
    controller = Controller(study.controller, rig.dt_s, study.identify_feedforward().inverse())
    ref = study.references["trajectory"]
    peer = simulate(rig, controller, ref, seed=study.seed)
    out: dict = {"paper_tracking_rms_N": peer.tracking_error().rms_N,
                 "paper_tracking_rms_after_change_N": peer.tracking_error(after_change_s=AFTER_CHANGE_S).rms_N}
    t0 = time.perf_counter()
    res = learn(controller, rig, ref, iterations=args.iterations, seed=study.seed)
    d = res.to_dict()
    out.update({k: d[k] for k in ("tracking_rms_N", "tracking_rms_after_change_N", "tracking_rms_from_start_N",
                                  "tracking_rms_outside_transitions_N", "tracking_rms_pct_of_range", "causal_floor_N",
                                  "preview_floor_N", "preview_floor_branch_N", "plan_rms_after_change_N",
                                  "over_preview_floor_ratio", "iterations", "trials", "stop_reason", "converged",
                                  "best_iteration", "preview_s", "method", "noise_floor_N", "plan_slew_fraction",
                                  "learning")})
    out["over_branch_floor_ratio"] = d["tracking_rms_N"] / d["preview_floor_branch_N"]
    out["learned_over_paper_ratio"] = d["tracking_rms_N"] / out["paper_tracking_rms_N"]
    out["nominal_seconds"] = time.perf_counter() - t0
    print(f"default law ({d['method']}): {d['tracking_rms_N']:.3f} N after {d['trials']} trials (branch floor "
          f"{d['preview_floor_branch_N']:.3f} N), {d['tracking_rms_outside_transitions_N']:.3f} N outside the "
          "transitions", flush=True)
    for method, prefix in (("norm-optimal", ""), ("p-type", "p_type_")):
        full = learn(controller, rig, ref, iterations=args.iterations, seed=study.seed, method=method, stop_gain=None)
        history = [float(h.tracking_rms_N) for h in full.history]
        out[f"{prefix}trials_to_within_1p1"] = full.trials_to_within_1p1
        out[f"{prefix}history_rms_N"] = history
        out[f"{prefix}history_after_change_N"] = [float(h.tracking_rms_after_change_N) for h in full.history]
        if prefix:
            out["p_type_tracking_rms_N"] = full.tracking_rms_N
        print(f"{method}, every trial: {' '.join(f'{x:.3f}' for x in history)}; within 1.1 x the best from trial "
              f"{full.trials_to_within_1p1}", flush=True)
    if not args.no_trade_off:
        out["trade_off"] = []
        for w in (3.0, 10.0, 30.0):
            r = learn(controller, rig, ref, iterations=args.iterations, seed=study.seed, after_change_weight=w)
            out["trade_off"].append({"after_change_weight": w, "tracking_rms_N": r.tracking_rms_N,
                                     "tracking_rms_after_change_N": r.tracking_rms_after_change_N})
        front = plan_front(study.plant, ref, [0.0, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0, 1e3, 1e4])
        out["plan_front"] = front
        for key in ("", "_from_start"):
            meets = [f[f"rms_N{key}"] for f in front if f[f"rms_after_change_N{key}"] <= 0.15]
            out[f"plan_least_rms_with_after_change_le_0.15_N{key}"] = min(meets) if meets else None
    if args.plants:
        out.update(monte_carlo(controller, rig, ref, args.plants, args.iterations, study.seed))
    return out


def monte_carlo(controller, rig, ref, plants: int, iterations: int, seed: int) -> dict:
    t0 = time.perf_counter()
    mc = learn(controller, rig, ref, iterations=iterations, plants=plants, seed=seed)
    m = mc.to_dict()
    rows = np.array([np.atleast_1d(h.tracking_rms_N) for h in mc.history])
    limits = (controller.gains.u_min_V, controller.gains.u_max_V)
    print(f"{plants} Monte Carlo plants: {m['converged_plants']} converged, {m['monotone_plants']} monotone, worst "
          f"{m['tracking_rms_N']:.3f} N ({time.perf_counter() - t0:.0f} s)", flush=True)
    return {"mc_plants": plants, "mc_converged_plants": m["converged_plants"],
            "mc_converged_fraction": m["converged_plants"] / plants,
            "mc_monotone_fraction": m["monotone_plants"] / plants, "mc_diverged_plants": m["diverged_plants"],
            "mc_trials_max": m["trials"], "mc_worst_tracking_rms_N": m["tracking_rms_N"],
            "mc_worst_tracking_rms_after_change_N": m["tracking_rms_after_change_N"],
            # as the validation scores: leaving out the samples where the command sat at its limit (plants
            # whose stacks cannot reach 100 N within the 110 V the controller may give)
            "mc_worst_tracking_rms_unsaturated_N": float(np.max(mc.run.tracking_error(u_range=limits).rms_N)),
            "mc_saturated_plants": int(np.sum(mc.run.tracking_error(u_range=limits).saturated_fraction > 0)),
            "mc_median_tracking_rms_N": float(np.median(rows[np.asarray(mc.best), np.arange(rows.shape[1])])),
            "mc_noise_floor_N": m["noise_floor_N"], "mc_seconds": time.perf_counter() - t0}


def machine_axis(folder: Path) -> dict:
    from piezopreload.artifacts.gainset import GainSet
    from piezopreload.artifacts.learned import LearnedSignal
    from piezopreload.artifacts.learning import LearningRecord
    from piezopreload.artifacts.plant import DesignedPlant
    from piezopreload.pipeline import run_study
    from piezopreload.progress import Progress
    from piezopreload.tuning.learning import law_for
    from piezopreload.tuning.preview import plan_preview

    study = load_study("machine_axis")
    t0 = time.perf_counter()
    run_study(study, folder, progress=Progress(quiet=True))
    out: dict = {"machine_axis_study_seconds": time.perf_counter() - t0}
    record = LearningRecord.load(folder / "learn" / "learning.json")
    out["machine_axis_trials_per_pass"] = record.trials_per_pass
    out["machine_axis_stopped_within_1p1_per_pass"] = [p.trials_to_within_1p1 for p in record.passes]
    out["machine_axis_tracking_rms_N_per_pass"] = [p.tracking_rms_N for p in record.passes]
    params = DesignedPlant.load(folder / "plant.json").rig  # the plant the learn stage ran on
    controller = GainSet.load(folder / "gains.json").controller()
    references = [LearnedSignal.load(path).reference for path in record.signal_paths(folder / "learn")]
    learner, results = schedule_learner(params, controller, iterations=8, preview_s=None, method="norm-optimal",
                                        seed=study.seed, stop_gain=None)
    for ref in references:
        learner(ref)
    per_pass = [int(within_1p1(np.array([float(h.tracking_rms_N) for h in r.history]))[0]) for r in results]
    out["machine_axis_trials_to_within_1p1"] = max(per_pass)
    out["machine_axis_trials_to_within_1p1_per_pass"] = per_pass
    out["machine_axis_history_rms_N_per_pass"] = [[float(h.tracking_rms_N) for h in r.history] for r in results]
    out["machine_axis_noise_floor_N_per_pass"] = [r.noise_floor_N for r in results]
    print(f"machine axis: {record.trials_per_pass} trials per pass as the learn stage ran them; every trial: "
          f"{out['machine_axis_history_rms_N_per_pass']}", flush=True)
    # one update of the default law on the whole schedule (the first pass's reference)
    preview = plan_preview(params, controller, references[0])
    law = law_for("norm-optimal", params, controller, preview, seed=study.seed)
    run = simulate(Rig(params), controller, preview.setpoint, seed=study.seed, ff_extra_V=preview.ff_extra_V)
    e = preview.target_N - run.measured_N
    times = []
    for _ in range(3):
        t1 = time.perf_counter()
        law.update(preview.ff_extra_V, e, run.command_V, run.voltage_V)
        times.append(time.perf_counter() - t1)
    out.update({"norm_optimal_schedule_s_per_trial": times[0],
                "norm_optimal_schedule_s_per_later_trial": min(times[1:]),
                "norm_optimal_schedule_samples": int(preview.target_N.size)})
    print(f"one norm-optimal update on the schedule's {preview.target_N.size} samples: {times[0]:.2f} s "
          f"(later ones {min(times[1:]):.2f} s)", flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plants", type=int, default=50, help="Monte Carlo plants (0: none)")
    ap.add_argument("--iterations", type=int, default=10)
    ap.add_argument("--no-trade-off", action="store_true",
                    help="leave out the after-change trade-off and the plans' front")
    ap.add_argument("--no-machine", action="store_true", help="leave out the machine axis (a minute for its study)")
    args = ap.parse_args()
    out = paper(args)
    if not args.no_machine:
        with tempfile.TemporaryDirectory() as tmp:
            out.update(machine_axis(Path(tmp) / "machine_axis"))
    print(json.dumps(out))


if __name__ == "__main__":
    main()
