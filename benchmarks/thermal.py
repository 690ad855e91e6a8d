"""The shift's thermal model: the averaged slow model against the same axis stepped through every cycle.

* The default study's schedule (the design's least-friction plan on its machining cycle, the study's
  ``[thermal]`` table) over its shift (8 h) from a cold axis. Ours: the cycle-averaged heat and film drive the
  slow model, solved exactly at the end of each hour (:meth:`CycleSources.shift`). The peer: the same network
  stepped through every cycle in 0.1 s steps (Crank-Nicolson, each step's own heat where the nut is and its own
  film; :class:`~piezopreload.models.thermal.FineMarch`). Each is timed per simulated hour
  (``shift_vs_fine_ratio``: ours over the peer's, both in this run); their agreement is the largest difference
  between the stepped network's mean over the last cycle of each hour and the slow model's over the same time
  (``temperature_agreement_K``, every node; at the cycle's end, its ripple included:
  ``end_of_cycle_difference_K``). The step's own convergence: the first hour again in 0.05 s steps.
* The closed forms: a uniformly heated screw with insulated ends against a lumped body's step response; the
  steady screw with its ends at the ambient against the fin with a distributed source, at the study's number of
  volumes, and the order of convergence from 30 to 240 volumes; the energy balance of the exact shift (Simpson's
  rule on its losses).
* Both heat models on a grid of preloads and speeds for HIWIN's R40-10T4 ground double nut.

The machine is shared: times are noisy; the ratio compares two runs of the same minute. The last line printed is
one JSON object.
"""

from __future__ import annotations

import json
import math
import statistics
import time
from typing import Any

import numpy as np

from piezopreload.design.thermal import CycleLoad, cycle_sources
from piezopreload.models.ballscrew import BallScrew
from piezopreload.models.thermal import STEEL_HEAT_CAPACITY_J_PER_M3K, AxisModel, ScrewBody
from piezopreload.study import load_study

STEP_S = 0.1
REPEATS = 5


def _median_time(fn, repeats: int = REPEATS):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def _shift(study):
    """The slow model against the stepped network over the study's shift."""
    schedule, table = study.preload_schedule, study.thermal
    screw, drive = study.design_spec.screw(study.solved.design_point()), study.design_spec.feed_drive
    prof = schedule.profile
    cycle = CycleLoad.on_profile(prof.time_s, schedule.preload_N, prof.speed_rpm, prof.axial_load_N)
    sources_s, sources = _median_time(lambda: cycle_sources(screw, drive, table, cycle))
    period, shift_s = cycle.period_s, 3600.0 * table.shift_h
    cycles = int(shift_s // period)
    hour_ends = [int(round(3600.0 * h / period)) for h in range(1, int(table.shift_h) + 1)]  # cycles to each hour
    ours_s, _ = _median_time(lambda: sources.shift(np.arange(1.0, table.shift_h + 1.0) * 3600.0))
    march = sources.fine(STEP_S)
    t0 = time.perf_counter()
    ends, means, _ = march.run(cycles)
    fine_s = time.perf_counter() - t0
    diffs, ripple = [], []
    for k in hour_ends:
        k = min(k, cycles)
        window = (k - 1) * march.period_s + np.linspace(0.0, march.period_s, 241)
        slow = sources.shift(window)
        diffs.append(float(np.max(np.abs(means[k - 1] - slow.mean(axis=0)))))
        ripple.append(float(np.max(np.abs(ends[k - 1] - slow[-1]))))  # the cycle's end: its ripple is in it
    hour = int(round(3600.0 / period))
    _, half_means, _ = sources.fine(0.5 * STEP_S).run(hour)
    step_error = float(np.max(np.abs(half_means[-1] - means[hour - 1])))
    n = sources.model.volumes
    rise = sources.shift([shift_s])[0]
    return {"cycles": cycles, "period_s": period, "steps_per_cycle": int(march.h.size),
            "shift_s_per_hour": ours_s / table.shift_h, "fine_s_per_hour": fine_s * 3600.0 / (cycles * period),
            "agreement_per_hour_K": diffs, "end_of_cycle_K": max(ripple), "fine_step_convergence_K": step_error,
            "screw_rise_max_K": float(rise[:n].max()), "nut_rise_K": float(rise[n]),
            "nut_heat_mean_W": float(cycle.mean(sources.nut_W)), "volumes": n, "sources_s": sources_s}


def _closed_forms(volumes: int) -> dict[str, float]:
    d, length, h, power = 0.032, 1.2, 20.0, 40.0
    body = ScrewBody(length, d, d)

    def axis(n: int, bearing: float) -> AxisModel:
        return AxisModel(body, n, (bearing, bearing), 500.0, 0.02, 900.0, 5.0, 5.0)

    model = axis(volumes, 0.0)
    q = np.zeros(model.size)
    q[:volumes] = power / volumes
    t = np.linspace(0.0, 8 * 3600.0, 97)
    tau = STEEL_HEAT_CAPACITY_J_PER_M3K * d / (4.0 * h)
    lumped = power / (h * math.pi * d * length) * (1.0 - np.exp(-t / tau))
    net = model.network(h, 8.0)
    rises = net.response(q, t)
    lumped_error = float(np.max(np.abs(rises[:, :volumes] - lumped[:, None])) / lumped.max())
    losses = net.losses_W(rises)
    lost = (t[1] - t[0]) / 3.0 * (losses[0] + losses[-1] + 4 * losses[1:-1:2].sum() + 2 * losses[2:-1:2].sum())
    balance = float(abs(model.capacities_J_per_K() @ rises[-1] + lost - q.sum() * t[-1]) / (q.sum() * t[-1]))
    perimeter = math.pi * d
    m = math.sqrt(h * perimeter / (body.conductivity_W_per_mK * body.area_m2))
    q_per_m = power / length
    errors = {}
    for n in sorted({30, 60, 120, 240, volumes}):
        fin = axis(n, math.inf)
        src = np.zeros(fin.size)
        src[:n] = q_per_m * fin.dx_m
        x = fin.centres_m
        exact = q_per_m / (h * perimeter) * (1.0 - np.cosh(m * (x - 0.5 * length)) / np.cosh(0.5 * m * length))
        errors[n] = float(np.max(np.abs(fin.network(h, 8.0).steady(src)[:n] - exact)) / exact.max())
    return {"lumped_step_error_rel": lumped_error, "lumped_time_constant_s": tau, "energy_balance_error_rel": balance,
            "fin_error_rel": errors[volumes], "fin_order": float(np.log2(errors[120] / errors[240]))}


def _heat_grid() -> dict[str, Any]:
    screw = BallScrew.from_catalogue(40.0, 10.0, 6.35, 4.0, c_dyn_N=37890.0, c0_N=94260.0)
    fractions = np.array([0.02, 0.05, 0.10])
    speeds = np.array([500.0, 1000.0, 2000.0, 3000.0])
    preload = fractions[:, None] * screw.dynamic_rating_N
    out: dict[str, Any] = {"screw": "HIWIN R40-10T4-RDI", "seal_torque_Nm": screw.seal_torque_Nm, "lubricant_vg": 68,
                              "temperature_C": 40.0, "preload_fraction_of_c_dyn": fractions.tolist(),
                              "speed_rpm": speeds.tolist()}
    for model in ("catalogue", "contact"):  # the open nut's: the seals' torque is the same in both, apart
        out[f"{model}_W"] = np.asarray(screw.friction_heat_W(preload, speeds[None, :], model=model, seal_torque_Nm=0.0),
                                       float).tolist()
    out["seals_W"] = (screw.seal_torque_Nm * speeds * np.pi / 30.0).tolist()
    return out


def main() -> None:
    study = load_study(progress=lambda _m: None)
    shift = _shift(study)
    ratio = shift["shift_s_per_hour"] / shift["fine_s_per_hour"]
    print(f"shift: {shift['cycles']} cycles of {shift['period_s']:.2f} s, {shift['volumes']} volumes; the slow model "
          f"{1e6 * shift['shift_s_per_hour']:.0f} us per simulated hour, the network stepped every {STEP_S} s "
          f"({shift['steps_per_cycle']} steps a cycle) {shift['fine_s_per_hour']:.2f} s per hour: ratio {ratio:.2e}; "
          f"the cycle's heat and where it enters, for both, {1e3 * shift['sources_s']:.0f} ms", flush=True)
    print("agreement over the last cycle of each hour (K): "
          + ", ".join(f"{d:.4f}" for d in shift["agreement_per_hour_K"])
          + f" (at the cycles' ends, the cycle's ripple in it: {shift['end_of_cycle_K']:.3f} K); the stepped "
            f"network's own step error (0.1 against 0.05 s, first hour) {shift['fine_step_convergence_K']:.1e} K",
          flush=True)
    print(f"the schedule's {shift['nut_heat_mean_W']:.1f} W: the screw up to {shift['screw_rise_max_K']:.2f} K, the "
          f"nut {shift['nut_rise_K']:.2f} K at the shift's end", flush=True)
    closed = _closed_forms(shift["volumes"])
    print(f"closed forms: lumped step response {closed['lumped_step_error_rel']:.1e} (tau "
          f"{closed['lumped_time_constant_s'] / 60:.1f} min), fin {closed['fin_error_rel']:.1e} at "
          f"{shift['volumes']} volumes (order {closed['fin_order']:.2f}), energy balance "
          f"{closed['energy_balance_error_rel']:.1e}", flush=True)
    grid = _heat_grid()
    print(f"heat of {grid['screw']} (W, the open nut, VG68 at 40 deg C; rows: preload "
          f"{grid['preload_fraction_of_c_dyn']} C_dyn, columns: {grid['speed_rpm']} rpm):")
    for model in ("catalogue", "contact"):
        rows = "; ".join(" ".join(f"{w:6.1f}" for w in row) for row in grid[f"{model}_W"])
        print(f"  {model:9s} {rows}")
    print(f"  its seals ({grid['seal_torque_Nm']:g} N m, Rexroth's table) add " + " ".join(f"{w:6.1f}"
                                                                                    for w in grid["seals_W"]))
    print(json.dumps({
        "shift_vs_fine_ratio": ratio, "temperature_agreement_K": max(shift["agreement_per_hour_K"]),
        "shift_us_per_hour": 1e6 * shift["shift_s_per_hour"], "fine_s_per_hour": shift["fine_s_per_hour"],
        "cycle_sources_s": shift["sources_s"],
        "end_of_cycle_difference_K": shift["end_of_cycle_K"], "fine_step_s": STEP_S,
        "fine_step_convergence_K": shift["fine_step_convergence_K"],
        "cycles": shift["cycles"], "volumes": shift["volumes"], "screw_rise_max_K": shift["screw_rise_max_K"],
        **closed, "heat_grid": grid}))


if __name__ == "__main__":
    main()
