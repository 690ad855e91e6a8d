"""The double-nut rigidity model against the catalogue rows, and its two constants left out.

Reads ``tests/data/ballscrew_rigidity.csv`` (sources: ``tests/data/ballscrew_rigidity_sources.toml``)
through the one reader of catalogue tables, ``piezopreload.design.catalogue`` (the tests use it too),
and prints:

* every row: the model's rigidity at the row's preload, the catalogue's, the error, and the
  paper's eq. (13) (Hertz only, all balls, rigid nut and screw) beside it;
* the largest and the RMS error over the checked rows, per vendor and over all, for the model
  and for eq. (13), and the model's error on the rows the vendors' own tables contradict;
* the leave-out checks of the two calibrated constants: the effective ball share fitted on
  THK's rows and checked on HIWIN's and the other way round; the P5 accuracy factor fitted on
  Rexroth's 7 % preload rows and checked on its 10 % rows;
* Rexroth's 10 % / 7 % rigidity ratio, catalogue against model (not fitted);
* the largest lambda L of the elastic load distribution and how far the nut law's first-order
  body term is from the exact shear-lag one.

The last line printed is one JSON object. Run from the repository root:
``.venv/bin/python benchmarks/ballscrew_rigidity.py``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from piezopreload.design.catalogue import (
    checked,
    error_stats,
    first_order_body_error,
    fit_accuracy,
    fit_share,
    largest_lambda_L,
    load_rows,
)
from piezopreload.models.ballscrew import ACCURACY_FACTOR_P5, EFFECTIVE_BALL_SHARE

#: the repository's catalogue table (a data file of the tests, which check the same rows)
CATALOGUE = Path(__file__).resolve().parent.parent / "tests" / "data" / "ballscrew_rigidity.csv"


def main() -> dict:
    rows = load_rows(CATALOGUE)
    good = checked(rows)
    print(f"{'row':32s} {'source':15s} {'d':>4s} {'P':>3s} {'D_w':>6s} {'i':>4s} {'F_p/C':>6s} "
          f"{'catalogue':>9s} {'model':>7s} {'error':>7s} {'eq.(13)':>8s}")
    for r in rows:
        mark = "" if r.check else "  (not checked)"
        print(f"{r.designation:32s} {r.source:15s} {r.nominal_diameter_mm:4.0f} {r.lead_mm:3.0f} {r.ball_mm:6.3f} "
              f"{r.turns:4.1f} {r.preload_fraction:6.2f} {r.rigidity_N_per_um:9.0f} {r.predicted_N_per_um():7.0f} "
              f"{r.error():+7.1%} {r.eq13_error():+8.1%}{mark}")

    out: dict = {"rows": len(rows), "rows_checked": len(good), "vendors": sorted({r.vendor for r in good}),
                 "effective_ball_share": EFFECTIVE_BALL_SHARE, "accuracy_factor_p5": ACCURACY_FACTOR_P5}
    print()
    for vendor in ("hiwin", "thk", "rexroth", None):
        sel = [r for r in good if vendor in (None, r.vendor)]
        model, eq13 = error_stats([r.error() for r in sel]), error_stats([r.eq13_error() for r in sel])
        name = vendor or "all"
        print(f"{name:8s} {model['n']:4d} rows: model max {model['max']:.1%} RMS {model['rms']:.1%}; "
              f"eq. (13) max {eq13['max']:.1%} RMS {eq13['rms']:.1%}")
        out[f"{name}_max_error"], out[f"{name}_rms_error"] = model["max"], model["rms"]
        out[f"{name}_eq13_max_error"], out[f"{name}_eq13_rms_error"] = eq13["max"], eq13["rms"]
    out["not_checked_errors"] = {r.designation: r.error() for r in rows if not r.check}
    print("not checked:", ", ".join(f"{k} {v:+.1%}" for k, v in out["not_checked_errors"].items()))

    # ---- the constants left out ----------------------------------------------------------
    theoretical = [r for r in good if r.basis == "theoretical"]
    share_all = fit_share(good)
    print(f"\neffective ball share: all theoretical rows {share_all:.4f} (module {EFFECTIVE_BALL_SHARE})")
    out["share_fit_all"] = share_all
    for fit_on, check_on in (("thk", "hiwin"), ("hiwin", "thk")):
        share = fit_share([r for r in theoretical if r.vendor == fit_on])
        stats = error_stats([r.error(share) for r in theoretical if r.vendor == check_on])
        print(f"  fitted on {fit_on} {share:.4f}: {check_on} max {stats['max']:.1%} RMS {stats['rms']:.1%}")
        out[f"share_fit_{fit_on}"] = share
        out[f"{check_on}_max_error_share_from_{fit_on}"] = stats["max"]
        out[f"{check_on}_rms_error_share_from_{fit_on}"] = stats["rms"]
    rexroth = [r for r in good if r.basis == "accuracy_p5"]
    f_all = fit_accuracy(good, share_all)
    f_7 = fit_accuracy([r for r in rexroth if r.preload_fraction < 0.085])
    stats = error_stats([r.error(accuracy_p5=f_7) for r in rexroth if r.preload_fraction > 0.085])
    print(f"accuracy factor P5: all Rexroth rows {f_all:.4f} (module {ACCURACY_FACTOR_P5}); fitted at 7 % "
          f"{f_7:.4f}: 10 % rows max {stats['max']:.1%} RMS {stats['rms']:.1%}")
    out.update(accuracy_fit_all=f_all, accuracy_fit_7=f_7, rexroth_10_max_error_accuracy_from_7=stats["max"],
               rexroth_10_rms_error_accuracy_from_7=stats["rms"])

    # ---- not fitted: the preload scaling and the load distribution ---------------------------
    pairs: dict = {}
    for r in rexroth:
        pairs.setdefault((r.nominal_diameter_mm, r.lead_mm, r.ball_mm, r.turns), {})[r.preload_fraction] = r
    cat = np.mean([p[0.1].rigidity_N_per_um / p[0.07].rigidity_N_per_um for p in pairs.values()])
    mod = np.mean([p[0.1].predicted_N_per_um() / p[0.07].predicted_N_per_um() for p in pairs.values()])
    print(f"Rexroth 10 % / 7 % rigidity: catalogue {cat:.4f}, model {mod:.4f}, Hertz alone {(10 / 7) ** (1 / 3):.4f}")
    lam_L = largest_lambda_L(rows)
    body = max(abs(first_order_body_error(r)) for r in rows)
    print(f"load distribution: lambda L up to {lam_L:.3f}; first-order body term within {body:.2%} of the exact one")
    out.update(rexroth_preload_ratio_catalogue=float(cat), rexroth_preload_ratio_model=float(mod),
               lambda_L_max=lam_L, first_order_body_error_max=body)
    return out


if __name__ == "__main__":
    print(json.dumps(main()))
