"""
Sweep the bolts' preload
========================

Sweep the bolts' preload and see what it does to the plant, the tuned loop and its worst Monte Carlo case.

It runs on the default study, the machine axis (``pp.load_study()``, studies/machine_axis.toml),
unless ``--study`` names another. The machine axis' plant is its design, so there the bolts' preload
is the design's, not an input (``[rig] bolt_preload_N`` is refused): the design sets it as low as
the failsafe requirement allows (the bolts alone hold ``[design] failsafe_load_N`` without lift-off,
``F_i = lift_off_margin * failsafe_load_N / 2^1.5``). So the sweep asks the design for each bolt
preload through that requirement, and the plant changes with it: the nuts' Hertz contacts are
stiffer at a higher preload, so the stacks push more force per volt at the bottom of their range.
On a study whose plant is its ``[rig]`` (``--study paper2021``) it sets ``[rig] bolt_preload_N``.

For each bolt preload the study is copied with it, the feedforward identified on the copy's plant,
the PID tuned around it and validated by Monte Carlo; the figure shows the plant's stiffness at the
bolts' preload (left) and the tuned settling time on the nominal plant and the worst Monte Carlo
plant's (right) against the bolts' preload.

Run it from the repository root::

    python examples/sweep_bolt_preload.py                  # the machine axis: 0.5, 1 and 2 times its design's
    python examples/sweep_bolt_preload.py --study paper2021 --preloads 20 25 30 --plants 50 --out sweep/
"""

import argparse
import math
from pathlib import Path

from matplotlib.figure import Figure

import piezopreload as pp

#: the preloads swept where none are given, as factors of the study's own bolts' preload
FACTORS = {"design": (0.5, 1.0, 2.0), "rig": (0.8, 1.0, 1.2)}


def with_bolt_preload(study: pp.Study, preload_N: float) -> pp.Study:
    """The study with the bolts' preload ``preload_N``: through the design's failsafe requirement where the plant
    is the design (the design's bolt preload is that requirement's least, where it binds), else in ``[rig]``."""
    if not study.plant_from_design:
        return study.replace(rig={"bolt_preload_N": preload_N})
    margin = study.design_spec.lift_off_margin
    return study.replace(design={"failsafe_load_N": preload_N * 2.0**1.5 / margin})


def bolt_preload_N(study: pp.Study) -> float:
    """The bolts' preload of the study's plant: the design's (the nuts' preload when the stacks push nothing), or
    ``[rig]``'s."""
    return study.designed_plant.bolt_preload_N if study.plant_from_design else float(study.plant.bolt_preload_N)


def sweep(study: pp.Study, preloads_N: list[float], plants: int) -> list[dict]:
    rows = []
    for preload in preloads_N:
        s = with_bolt_preload(study, preload)
        plant = s.plant
        feedforward = s.identify_feedforward()
        tuned = s.tune(feedforward=feedforward)
        gain_set = s.validate(tuned, feedforward, plants=plants, seed=0)
        worst = gain_set.validation.worst.settling_s
        rows.append({"asked_N": preload, "bolt_preload_N": bolt_preload_N(s),
                     "stiffness_at_bolts_N_per_um": float(plant.local_stiffness_N_per_um(0.0)),
                     "settling_s": tuned.row("tuned")["settling_s"], "worst_settling_s": worst,
                     "validated": gain_set.validated, "Kc_V_per_N": tuned.gains.Kc, "Ti_s": tuned.gains.Ti_s})
        r = rows[-1]
        print(f"bolts' preload {r['bolt_preload_N']:6.1f} N: plant {r['stiffness_at_bolts_N_per_um']:6.1f} N/um at "
              f"the bolts' preload, tuned settling {r['settling_s']:.3f} s, worst of {plants} plants {worst:.3f} s, "
              f"{gain_set.status}")
    return rows


def plot(rows: list[dict], study_name: str) -> Figure:
    fig = Figure(figsize=(9.0, 3.5), layout="constrained")
    left, right = fig.subplots(1, 2)
    x = [r["bolt_preload_N"] for r in rows]
    left.plot(x, [r["stiffness_at_bolts_N_per_um"] for r in rows], "o-", color="C2")
    left.set(xlabel="bolts' preload (N)", ylabel="force per um of stroke at the bolts' preload (N/um)",
             title="the plant")
    right.plot(x, [r["settling_s"] for r in rows], "o-", label="tuned, nominal plant")
    right.plot(x, [r["worst_settling_s"] for r in rows], "s--", label="worst Monte Carlo plant")
    right.set(xlabel="bolts' preload (N)", ylabel="settling time (s)", title="the tuned loop")
    right.legend()
    fig.suptitle(f"{study_name}: the bolts' preload")
    return fig


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description="Sweep the bolts' preload and see what it does to the plant, "
                                                 "the tuned loop and its worst Monte Carlo case.")
    parser.add_argument("--study", help="a shipped study's name or a study file (default: the machine axis)")
    parser.add_argument("--preloads", type=float, nargs="+",
                        help="bolts' preloads (N; default: 0.5, 1 and 2 times the design's, or 0.8, 1 and 1.2 times "
                             "[rig]'s)")
    parser.add_argument("--plants", type=int, default=200, help="Monte Carlo plants per preload")
    parser.add_argument("--out", default="sweep-out", help="folder for the figure")
    args = parser.parse_args(argv)
    study = pp.load_study(args.study)
    if args.preloads is None:
        own = bolt_preload_N(study)
        args.preloads = [round(f * own, 1) for f in FACTORS["design" if study.plant_from_design else "rig"]]
    if not all(math.isfinite(p) and p > 0 for p in args.preloads):
        parser.error(f"--preloads: each must be a number > 0, got {args.preloads}")
    rows = sweep(study, args.preloads, args.plants)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    plot(rows, study.name).savefig(out / "settling_vs_bolt_preload.png", dpi=120)
    print(f"wrote {out / 'settling_vs_bolt_preload.png'}")
    return rows


if __name__ == "__main__":
    main()
