"""From your own loop measurement to gains in LabVIEW's and a PLC's units.

1. Read a measured voltage-to-force loop (a CSV with a header ``time_s,voltage_V,force_N``).
2. Identify a classical P-I model on the first part of the record and check it on the rest
   (errors in % of the force span, beside a straight line).
3. Use the record as the study's feedforward data: tune the PID around the rig compensated by
   that model, validate the gains by Monte Carlo, save the gain set and export it for LabVIEW
   (Ti and Td in minutes) and for a PLC (Kp, Tn, Tv in seconds).

    python examples/identify_and_export.py loop.csv --train-until 4.0 --out my-gains/
"""

import argparse
from pathlib import Path

import piezopreload as pp


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", help="the measured loop: time_s,voltage_V,force_N")
    parser.add_argument("--study", help="study file whose rig is tuned on (default: the paper's)")
    parser.add_argument("--train-until", type=float, help="end of the training window in s (default: 70 %% of it)")
    parser.add_argument("--operators", type=int, default=40, help="play operators (default 40, as the paper)")
    parser.add_argument("--plants", type=int, default=200, help="Monte Carlo plants")
    parser.add_argument("--out", default="gains-out", help="folder for the model, the gain set and the exports")
    args = parser.parse_args(argv)
    out = Path(args.out)

    # 1-2: identify on a training window, check on the held-out rest
    record = pp.read_record(args.data)
    t0, t1 = float(record.time_s[0]), float(record.time_s[-1])
    split = args.train_until if args.train_until is not None else t0 + 0.7 * (t1 - t0)
    fit = pp.identify(record, model="classical", operators=args.operators, train=pp.Window(t0, split),
                      test=pp.Window(split, t1))
    s = fit.to_dict()
    print(f"held-out {split:g}-{t1:g} s: RMS {s['test']['rms_pct']:.3f} %, max {s['test']['max_pct']:.3f} % of the "
          f"{s['output_span']:.4g} N span (a straight line: {s['line_test']['rms_pct']:.2f} % RMS)")
    fit.save(out / "model.json")
    fit.plot().savefig(out / "model.png", dpi=120)

    # 3: the record as the study's feedforward data; tune, validate, export
    study = pp.load_study(args.study).replace(feedforward={"data": str(Path(args.data).resolve()),
                                                           "n_operators": args.operators})
    tuned = study.tune()  # identifies the feedforward from [feedforward] data
    gain_set = tuned.validate(plants=args.plants, seed=0).save(out / "gains.json")
    print(f"gains Kc {gain_set.gains.Kc:.4g} V/N, Ti {gain_set.gains.Ti_s:.4g} s, Td {gain_set.gains.Td_s:.4g} s: "
          f"{gain_set.status} on {args.plants} plants")
    written = {"model": out / "model.json", "gains": out / "gains.json"}
    if gain_set.validated:  # only validated gains are exported
        for fmt, name in (("labview", "gains.labview.txt"), ("plc", "gains.plc.txt")):
            (out / name).write_text(gain_set.export(fmt))
            written[fmt] = out / name
    for what, path in written.items():
        print(f"wrote {what}: {path}")
    return {"fit": s, "gain_set": gain_set, "written": written}


if __name__ == "__main__":
    main()
