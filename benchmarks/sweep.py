"""An 8-point design sweep on 2 local worker processes, on a Dask LocalCluster, and one point after another.

The sweep: the repository's small study (``tests/data/small_study.toml``: the paper's rig and
gains, short references, 8 Monte Carlo plants) at 8 values of ``[tuning] ms_max``, the bound on
the maximum sensitivity the PID tuning keeps, 1.3 to 1.65 (every one validates; at 1.9 and 2.0 the
validation fails, which stops those points early): every point tunes, validates, compares,
exports, runs on the rig and reports its own gains; the design and the feedforward's
identification are the same at every point and are computed once per sweep.

The same sweep runs three times in this process, each into a fresh folder (so nothing is shared
between the runs), after one untimed run of the study in another process that puts the compiled
model code into the build cache:

1. ``serial_s``: ``study.sweep(..., workers=1)``, the points one after another in this process, each
   point's stages as ``piezopreload run`` runs them (its figures and Monte Carlo on the spare CPUs);
2. ``parallel_s``: ``workers=2``, two local worker processes (fresh ones: their start and imports are
   in the time), a point each at a time;
3. ``dask_s``: on a ``distributed.LocalCluster`` of 2 single-threaded worker processes, started
   before the clock (``dask_cluster_start_s``).

``sweep_parallel_vs_serial_ratio`` = parallel_s / serial_s (target <= 0.6 on 2 cores) and
``sweep_dask_vs_serial_ratio``; ``serial_cpus_used``, the serial run's CPU seconds over its wall
seconds: the CPUs it already kept busy on its own (its figures and Monte Carlo in worker processes,
the minimum-time bound beside the tuning), which bounds what two workers can gain on two CPUs;
``rows_identical``: the three runs' rows are equal, value for value (``rows_differ`` names the
columns where they are not). Each wall time has the load average beside it, and each run's CPU seconds (``runs``: this
process and the worker processes that ended; a Dask cluster's workers are counted when the cluster is closed, so its
``cpu_s`` is not comparable). The last line printed is one JSON object.

    python benchmarks/sweep.py [--study STUDY.toml] [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import piezopreload as pp
from piezopreload.progress import Progress

STUDY = Path(__file__).resolve().parents[1] / "tests" / "data" / "small_study.toml"
KEY, VALUES = "tuning.ms_max", [1.3, 1.35, 1.4, 1.45, 1.5, 1.55, 1.6, 1.65]


def _load() -> float:
    return os.getloadavg()[0]


def _cpu_s() -> float:
    """CPU seconds of this process and of its children that have ended (the local workers, the Dask cluster's)."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def _timed(study: pp.Study, out: Path, **where: Any) -> tuple[float, list[dict[str, Any]], dict[str, float]]:
    load0, cpu0 = _load(), _cpu_s()
    t0 = time.perf_counter()
    result = study.sweep({KEY: VALUES}, out=out, progress=Progress(quiet=True), **where)
    seconds = time.perf_counter() - t0
    if result.failed:
        print(f"note: {len(result.failed)} point(s) failed in {out}: " + "; ".join(str(p.error) for p in result.failed))
    return seconds, result.rows, {"loadavg_before": load0, "loadavg_after": _load(), "cpu_s": _cpu_s() - cpu0}


def _differ(a: list[dict[str, Any]], b: list[dict[str, Any]]) -> list[str]:
    if len(a) != len(b):
        return ["(number of rows)"]
    return sorted({k for ra, rb in zip(a, b) for k in ra if ra[k] != rb.get(k)})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--study", default=str(STUDY), help="study file (default: the repository's small study)")
    parser.add_argument("--workers", type=int, default=2, help="local worker processes and Dask workers (default 2)")
    args = parser.parse_args()
    from distributed import LocalCluster

    study = pp.load_study(args.study)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        # the build cache warm (the compiled model code), in another process: each mode starts cold in memory
        subprocess.run([sys.executable, "-m", "piezopreload.cli", "run", args.study, "--out", str(root / "warm-up"),
                        "--quiet", "--json"], check=True, capture_output=True)
        serial_s, serial_rows, serial = _timed(study, root / "serial", workers=1)
        parallel_s, parallel_rows, parallel = _timed(study, root / "parallel", workers=args.workers)
        t0 = time.perf_counter()
        with LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                          dashboard_address=None) as cluster:
            start_s = time.perf_counter() - t0
            dask_s, dask_rows, dask = _timed(study, root / "dask", scheduler=cluster.scheduler_address)
    differ = sorted(set(_differ(serial_rows, parallel_rows)) | set(_differ(serial_rows, dask_rows)))
    print(json.dumps({
        "benchmark": "sweep", "study": study.name, "vary": {KEY: VALUES}, "points": len(VALUES),
        "workers": args.workers, "cpus": os.cpu_count(),
        "serial_s": round(serial_s, 2), "parallel_s": round(parallel_s, 2), "dask_s": round(dask_s, 2),
        "dask_cluster_start_s": round(start_s, 2),
        "sweep_parallel_vs_serial_ratio": round(parallel_s / serial_s, 3),
        "sweep_dask_vs_serial_ratio": round(dask_s / serial_s, 3),
        "rows_identical": not differ, "rows_differ": differ,
        "failed_points": sum(r["status"] == "failed" for r in serial_rows),
        "serial_cpus_used": round(serial["cpu_s"] / serial_s, 2),
        "runs": {"serial": serial, "parallel": parallel, "dask": dask},
    }))


if __name__ == "__main__":
    main()
