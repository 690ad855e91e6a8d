"""The one-command study, first run and second run, as a user types it.

``piezopreload run`` keys every stage on the hashes of its inputs; a second run of an
unchanged study only checks hashes. Every run is a separate process (the command a user types,
imports included):

1. into a fresh folder with an empty build cache (as on a fresh install): ``first_run_s``, with
   each stage's time, and ``compile_s``, the seconds the C compiler took in it (read from the
   cache's build log); target <= 30 s on a 2-core machine;
2. the same folder again: ``second_run_s``, ``second_run_ran`` (nothing), ``rerun_time_ratio``;
3. into another fresh folder with the build cache now warm: ``first_run_warm_cache_s``.

Beside each wall time, the CPU seconds it took (``first_run_cpu_s``: the process, its worker
processes and the compiler), which other work on a shared machine does not inflate, and the
load average the run saw.

``--study`` picks the study (default: the default study of ``piezopreload run``, the machine axis).
The last line printed is one JSON object.
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


def _cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _run(argv: list[str], cache: str) -> tuple[float, float, dict]:
    """Wall seconds, CPU seconds (the process and everything it waited for: workers, the compiler) and the output."""
    t0, c0 = time.perf_counter(), _cpu_s()
    proc = subprocess.run([sys.executable, "-m", "piezopreload.cli", *argv, "--json", "--quiet"],
                          capture_output=True, text=True, check=False, env={**os.environ, "XDG_CACHE_HOME": cache})
    seconds, cpu = time.perf_counter() - t0, _cpu_s() - c0
    if proc.returncode != 0:
        raise SystemExit(f"piezopreload {' '.join(argv)} failed ({proc.returncode}): {proc.stderr.strip()}")
    return seconds, cpu, json.loads(proc.stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--study", help="study file (default: the default study, studies/machine_axis.toml)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out, other, cache = str(Path(tmp) / "out"), str(Path(tmp) / "out-warm"), str(Path(tmp) / "cache")
        study = [args.study] if args.study else []
        first_s, first_cpu, first = _run(["run", *study, "--out", out], cache)
        log = Path(cache) / "piezopreload" / "builds.jsonl"
        builds = [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []
        second_s, _, second = _run(["run", *study, "--out", out], cache)
        warm_s, warm_cpu, _ = _run(["run", *study, "--out", other], cache)
    stages = {s["stage"]: round(s["seconds"], 2) for s in first["stages"]}
    compile_s = sum(b["seconds"] for b in builds)
    print(f"first run {first_s:.1f} s with an empty build cache ({len(builds)} libraries built in {compile_s:.1f} s; "
          f"stages: {stages}); second run {second_s:.2f} s, ran {second['ran'] or 'nothing'}; "
          f"a first run with the cache warm {warm_s:.1f} s; CPU {first_cpu:.1f} s and {warm_cpu:.1f} s "
          f"(load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)")
    print(json.dumps({
        "study": first["study"]["name"], "first_run_s": first_s, "compile_s": compile_s,
        "builds": {b["name"]: round(b["seconds"], 2) for b in builds}, "stage_seconds": stages,
        "second_run_s": second_s, "second_run_ran": second["ran"], "rerun_time_ratio": second_s / first_s,
        "first_run_warm_cache_s": warm_s, "first_run_cpu_s": first_cpu, "first_run_warm_cache_cpu_s": warm_cpu,
        "load_average_1min": os.getloadavg()[0],
    }))


if __name__ == "__main__":
    main()
