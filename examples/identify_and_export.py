"""
From a measured loop to exported gains
======================================

From a loop measurement to gains and a feedforward a LabVIEW program and a PLC run.

Study: the paper's, ``paper2021`` (the simulated rig calibrated to Zhang, Jin, Lin (2021), its
25 -> 60 N step and 25-100 N staircase), unless ``--study`` names another.

1. The loop: a measured voltage-to-force loop (a CSV with a header ``time_s,voltage_V,force_N``).
   Without one (the default), the study's own loop measurement (``[feedforward]``: 0-100 V at
   0.5 Hz on the paper's rig) is simulated and written to ``OUT/loop.csv``, a stand-in for yours.
2. Identify a classical P-I model on the first 70 % of the record and check it on the rest
   (errors in % of the force span, beside a straight line); save it (``OUT/model.json``) and export
   it alone as the PLC's feedforward function block (``OUT/feedforward.plc.st``).
3. Use the record as the study's feedforward data: a loop whose forces do not cover the study's
   references is refused here, naming both ranges; then tune the PID around the rig compensated
   by that model, validate the gains by Monte Carlo (the study's ``[validation] plants``), save the
   gain set and, if it is validated, export it for LabVIEW (Ti and Td in minutes, the feedforward's
   tables) and for a PLC (Structured Text: the whole controller step as a function block).

Run it from the repository root::

    python examples/identify_and_export.py [loop.csv] [--study paper2021] [--out gains-out/]
"""

import argparse
from pathlib import Path

import piezopreload as pp
from piezopreload.core.tables import write_csv


def _loop(args: argparse.Namespace, study: pp.Study, out: Path) -> Path:
    """The measured loop's path; without one, the study's loop measurement simulated and written to out/loop.csv."""
    if args.data is not None:
        return Path(args.data).resolve()
    loop = study.identify_feedforward().loop
    path = out / "loop.csv"
    write_csv(path, {"time_s": loop.time_s, "voltage_V": loop.input, "force_N": loop.output},
              f"the loop measurement of study {study.name}, simulated on its rig: a stand-in for a measured one")
    print(f"no loop given: simulated the study's loop measurement on its rig -> {path}")
    return path


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description="From a loop measurement to gains and a feedforward a LabVIEW program "
                                                 "and a PLC run.")
    parser.add_argument("data", nargs="?", help="the measured loop: time_s,voltage_V,force_N (default: simulated)")
    parser.add_argument("--study", default="paper2021", help="the study tuned on (default: paper2021, the paper's)")
    parser.add_argument("--operators", type=int, default=40, help="play operators (default 40, as the paper)")
    parser.add_argument("--plants", type=int, help="Monte Carlo plants (default: the study's [validation] plants)")
    parser.add_argument("--out", default="gains-out",
                        help="folder for the loop, the model, the gain set and the exports")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    study = pp.load_study(args.study)
    low, high = study.reference_range_N
    print(f"study {study.name}: {study.title}; its references span {low:g} to {high:g} N")

    # 1-2: the loop; identify on a training window, check on the held-out rest; the model alone for a PLC
    loop = _loop(args, study, out)
    record = pp.read_record(loop)
    t0, t1 = float(record.time_s[0]), float(record.time_s[-1])
    split = t0 + 0.7 * (t1 - t0)
    result = pp.identify(record, model="classical", operators=args.operators, train=pp.Window(t0, split),
                         test=pp.Window(split, t1))
    print(result)
    model = result.save(out / "model.json")
    (out / "feedforward.plc.st").write_text(pp.export(model, "plc", sample_period_s=study.rig.sample_period_s))

    # 3: the record as the study's feedforward data (refused here if it does not cover the references); tune,
    # validate, export
    study = study.replace(feedforward={"data": str(loop), "n_operators": args.operators})
    tuned = study.tune()
    gain_set = study.validate(tuned, plants=args.plants, seed=0).save(out / "gains.json")
    g = gain_set.gains
    print(f"gains Kc {g.Kc:.4g} V/N, Ti {g.Ti_s:.4g} s, Td {g.Td_s:.4g} s: {gain_set.status} on "
          f"{gain_set.validation.n_plants} plants of study {study.name}")
    written = {"loop": loop, "model": out / "model.json", "feedforward": out / "feedforward.plc.st",
               "gains": out / "gains.json"}
    if gain_set.validated:  # only validated gains are exported
        for fmt, name in (("labview", "gains.labview.txt"), ("plc", "gains.plc.st")):
            (out / name).write_text(pp.export(gain_set, fmt))
            written[fmt] = out / name
    for what, path in written.items():
        print(f"wrote {what}: {path}")
    return {"study": study.name, "identification": result, "gain_set": gain_set, "written": written}


if __name__ == "__main__":
    main()
