"""``identify``: a P-I hysteresis model from a measured record."""

from __future__ import annotations

import argparse
from typing import Any

from piezopreload.cli._common import (
    json_flag,
    nonnegative_float,
    positive_int,
    time_constants,
    time_window,
)


# --------------------------------------------------------------------------------------
# identify
# --------------------------------------------------------------------------------------
def register_identify(sub: Any) -> None:
    """identify a P-I hysteresis model from a measured record"""
    from piezopreload.tuning.identify import MODELS

    p = sub.add_parser(
        "identify",
        description=(
            "Identify the weights of a Prandtl-Ishlinskii hysteresis model from a measured "
            "input/output record as a constrained QP (cvxpy + Clarabel), and report train and test "
            "errors in % of the output span beside a straight line and the paper's own method. "
            "Without DATA, the measured piezo record shipped with the package is used."),
        epilog=(
            "CSV: comma separated; lines starting with # are comments. With a header the columns are "
            "found by name (time_s, voltage_V and one output such as force_N or displacement_um); "
            "otherwise give --no-header --columns time=1,input=3:voltage_V,output=2:displacement_um "
            "(0-based indices, optional name with unit after ':')."))
    p.add_argument("data", nargs="?", metavar="DATA.csv", help="measured record (default: the shipped one)")
    p.add_argument("--columns", help="where time, input and output are: time=I,input=J,output=K")
    p.add_argument("--no-header", action="store_true", help="the file has no header line")
    p.add_argument("--model", choices=[*MODELS, *(m + "+creep" for m in MODELS)], default="classical",
                   help="classical: eq. (15); paper-asymmetric: eq. (18); modified: Kuhnen's model "
                        "with dead-zone output operators and an exact inverse (default: classical); "
                        "'+creep' as --creep")
    p.add_argument("--creep", action="store_true",
                   help="add creep (first-order lags on the input) identified in the same QP; the output also "
                        "gives the test error of the model refitted without creep")
    p.add_argument("--creep-time-constants", metavar="TAU,...", type=time_constants,
                   help="the creep lags' time constants in s, increasing (default: one per decade from 0.01 s "
                        "to the record's length)")
    p.add_argument("--operators", type=positive_int, default=40, help="number of play operators (default 40)")
    p.add_argument("--train", metavar="T0:T1", help="training window in s (default: first 70 %% of the record)")
    p.add_argument("--test", metavar="T0:T1", help="test window in s (default: after the training window)")
    p.add_argument("--ridge", type=nonnegative_float, default=0.0,
                   help="ridge weight on the scaled weights (default 0)")
    p.add_argument("--out", metavar="model.json", help="write the identified model as an artifact")
    json_flag(p)
    p.set_defaults(run=_cmd_identify, show=_print_identify)


def _cmd_identify(args: argparse.Namespace) -> dict[str, Any]:
    from piezopreload.core.tables import ColumnSpec, parse_columns, read_record
    from piezopreload.data import SHIPPED_COLUMNS, shipped_data
    from piezopreload.tuning.identification import identify

    columns: dict[str, ColumnSpec] | None
    if args.data is None:
        path, columns, header = shipped_data(), parse_columns(SHIPPED_COLUMNS), False
    else:
        path, header = args.data, not args.no_header
        columns = parse_columns(args.columns) if args.columns else None
    result = identify(read_record(path, columns=columns, header=header), model=args.model,
                      operators=args.operators, train=time_window(args.train, "--train"),
                      test=time_window(args.test, "--test"), ridge=args.ridge, creep=args.creep,
                      creep_time_constants_s=args.creep_time_constants)
    if args.out is not None:
        result.save(args.out)
    return {**result.to_dict(), "out": args.out}


def _print_identify(s: dict[str, Any]) -> None:
    d, sv = s["data"], s["solver"]
    unit = s["output_unit"] or "output units"
    print(f"data      {d['path']} ({d['samples']} samples; input {d['input']}, output {d['output']})")
    print(f"model     {s['model']}, {s['operators']} play operators, "
          f"{'invertible' if s['invertible'] else 'not invertible'}")
    print(f"solver    {sv['name']}: {sv['status']}{', active set polished' if sv['polished'] else ''}; "
          f"QP {1e3 * sv['qp_seconds']:.1f} ms, whole fit {1e3 * sv['fit_seconds']:.0f} ms")
    print(f"errors in % of the output span ({s['output_span']:.4g} {unit}):")
    print(f"  {'':40s}{'RMS':>8s}{'max':>8s}")
    rows = [(f"train {s['train']['window_s'][0]:g}-{s['train']['window_s'][1]:g} s", s["train"])]
    if s["test"] is not None:
        rows += [(f"test  {s['test']['window_s'][0]:g}-{s['test']['window_s'][1]:g} s", s["test"]),
                 ("test, best straight line", s["line_test"])]
    if s["paper_method_test"] is not None:
        rows.append(("test, the paper's method (eq. 17)", s["paper_method_test"]))
    if s.get("without_creep") and s["without_creep"]["test"] is not None:
        rows.append((f"test, {s['without_creep']['model']} without creep", s["without_creep"]["test"]))
    for label, e in rows:
        print(f"  {label:40s}{e['rms_pct']:8.3f}{e['max_pct']:8.3f}")
    if s.get("paper_method_note"):
        print(f"  the paper's method (eq. 17) could not run: {s['paper_method_note']}")
    for c in [s["creep"]] if s.get("creep") else []:
        print("creep     " + ", ".join(f"{w:.4g} at {tau:g} s" for tau, w in zip(c["time_constants_s"], c["weights"]))
              + f" ({unit} per input unit); without creep: refitted, not zeroed")
    if s["out"]:
        print(f"wrote     {s['out']}")


