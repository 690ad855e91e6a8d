"""The one-command study: a first run against a second run of the same study.

``piezopreload run`` keys every stage on the hashes of its inputs; a second run of an
unchanged study should only check hashes. Both runs are separate processes (the command a
user types, imports included) into a fresh folder; ``rerun_time_ratio`` is the second run's
wall time over the first's (target < 0.10). ``--study`` picks the study (default: the
paper's, about two and a half minutes on two cores).

The last line printed is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _run(argv: list[str]) -> tuple[float, dict]:
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "piezopreload.cli", *argv, "--json", "--quiet"],
                          capture_output=True, text=True, check=False)
    seconds = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"piezopreload {' '.join(argv)} failed ({proc.returncode}): {proc.stderr.strip()}")
    return seconds, json.loads(proc.stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--study", help="study file (default: the paper's)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = str(Path(tmp) / "out")
        study = [args.study] if args.study else []
        first_s, first = _run(["run", *study, "--out", out])
        second_s, second = _run(["run", *study, "--out", out])
    stages = {s["stage"]: round(s["seconds"], 2) for s in first["stages"]}
    print(f"first run {first_s:.1f} s (stages: {stages}); second run {second_s:.2f} s, ran {second['ran'] or 'nothing'}")
    print(json.dumps({
        "study": first["study"]["name"], "first_run_s": first_s, "second_run_s": second_s,
        "second_run_ran": second["ran"], "stage_seconds": stages, "rerun_time_ratio": second_s / first_s,
    }))


if __name__ == "__main__":
    main()
