"""``identify``: a P-I hysteresis model from a measured record."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

from piezopreload.cli._common import (
    Written,
    json_flag,
    nonnegative_float,
    positive_int,
    time_constants,
    time_window,
)

if TYPE_CHECKING:
    from piezopreload.tuning.identification import Identification


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


def _cmd_identify(args: argparse.Namespace) -> Written[Identification]:
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
    return Written(result, args.out)


def _print_identify(w: Written[Identification]) -> None:
    result = w.result
    r, d, sv = result.record, result.data, result.record.solver
    unit = r.units.output or "output units"
    print(f"data      {d.path} ({d.time_s.size} samples; input {d.input_name}, output {d.output_name})")
    print(f"model     {r.model.kind}, {r.model.n_operators} play operators, "
          f"{'invertible' if r.model.invertible else 'not invertible'}")
    print(f"solver    {sv.name}: {sv.status}{', active set polished' if sv.polished else ''}; "
          f"QP {1e3 * sv.qp_seconds:.1f} ms, whole fit {1e3 * sv.fit_seconds:.0f} ms")
    print(f"errors in % of the output span ({r.output_span:.4g} {unit}):")
    print(f"  {'':40s}{'RMS':>8s}{'max':>8s}")
    from piezopreload.tuning.identification import error_rows

    for label, e in error_rows(r):
        print(f"  {label:40s}{e.rms_pct:8.3f}{e.max_pct:8.3f}")
    if r.paper_method_note:
        print(f"  the paper's method (eq. 17) could not run: {r.paper_method_note}")
    from piezopreload.models.hysteresis import CreepPI

    if isinstance(r.model, CreepPI):
        c = r.model.creep
        print("creep     " + ", ".join(f"{c_j:.4g} at {tau:g} s" for tau, c_j in zip(c.time_constants_s, c.weights))
              + f" ({unit} per input unit); without creep: refitted, not zeroed")
    if w.out:
        print(f"wrote     {w.out}")
