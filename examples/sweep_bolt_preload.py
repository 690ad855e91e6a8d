"""Sweep the bolt preload and see what it does to the tuned loop and its worst Monte Carlo case.

For each bolt preload the study is copied with that value, the feedforward identified on the
changed rig, the PID tuned around it and validated by Monte Carlo; the figure shows the tuned
settling time (nominal rig, with the feedforward) and the validation's worst settling time
against the bolt preload.

    python examples/sweep_bolt_preload.py                          # the paper's study, 20-30 N
    python examples/sweep_bolt_preload.py --study my.toml --preloads 20 25 --plants 50 --out sweep/
"""

import argparse
from pathlib import Path

from matplotlib.figure import Figure

import piezopreload as pp


def sweep(study: pp.Study, preloads_N: list[float], plants: int) -> list[dict]:
    rows = []
    for preload in preloads_N:
        s = study.replace(rig={"bolt_preload_N": preload})
        tuned = s.tune(feedforward=s.identify_feedforward())
        gain_set = tuned.validate(plants=plants, seed=0)
        worst = gain_set.validation.worst.settling_s
        rows.append({"bolt_preload_N": preload, "settling_s": tuned.row("tuned")["settling_s"],
                     "worst_settling_s": worst, "validated": gain_set.validated,
                     "Kc_V_per_N": tuned.gains.Kc, "Ti_s": tuned.gains.Ti_s})
        print(f"bolt preload {preload:5.1f} N: tuned settling {rows[-1]['settling_s']:.3f} s, "
              f"worst of {plants} plants {worst:.3f} s, {gain_set.status}")
    return rows


def plot(rows: list[dict]) -> Figure:
    fig = Figure(figsize=(5.5, 3.5), layout="constrained")
    ax = fig.subplots()
    x = [r["bolt_preload_N"] for r in rows]
    ax.plot(x, [r["settling_s"] for r in rows], "o-", label="tuned, nominal rig")
    ax.plot(x, [r["worst_settling_s"] for r in rows], "s--", label="worst Monte Carlo plant")
    ax.set(xlabel="bolt preload (N)", ylabel="settling time (s)", title="the tuned loop against the bolt preload")
    ax.legend()
    return fig


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--study", help="study file (default: the paper's)")
    parser.add_argument("--preloads", type=float, nargs="+", default=[20.0, 25.0, 30.0], help="bolt preloads (N)")
    parser.add_argument("--plants", type=int, default=200, help="Monte Carlo plants per preload")
    parser.add_argument("--out", default="sweep-out", help="folder for the figure")
    args = parser.parse_args(argv)
    rows = sweep(pp.load_study(args.study), args.preloads, args.plants)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    plot(rows).savefig(out / "settling_vs_bolt_preload.png", dpi=120)
    print(f"wrote {out / 'settling_vs_bolt_preload.png'}")
    return rows


if __name__ == "__main__":
    main()
