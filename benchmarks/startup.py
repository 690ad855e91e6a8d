"""The front door's cost: ``import piezopreload``, ``piezopreload --help`` and a rerun that runs nothing.

Each is a fresh process, timed from its start to its exit, beside ``python -c "import numpy"`` in the
same run (the peer every script pays anyway): the three commands take turns, ``--repeats`` times
each, and the medians are compared. A warm-up round first lets Python write the package's bytecode
(the figures are for a package as it runs after its first import; the environment's
``PYTHONDONTWRITEBYTECODE`` is dropped for the timed processes, as it is on a user's machine).

* ``import_vs_numpy_ratio``: ``python -c "import piezopreload"`` over ``python -c "import numpy"``
  (target <= 2): the front door imports its names when they are first used.
* ``help_vs_numpy_ratio``: ``piezopreload --help`` over the same (target <= 3): the command line
  lists its subcommands without loading the floors.
* ``noop_rerun_s``: ``piezopreload run --out DIR`` on the default study when every stage is up to
  date (target <= 1.5 s): the study is read and checked, each stage's key computed from the hashes
  of its inputs and code and compared, nothing runs. The study is first run into ``DIR`` (a
  temporary folder unless ``--out`` names one that holds a run; the first run takes minutes) and
  the rerun is checked to have run nothing.

``--profile`` adds where a no-op rerun spends its time (cProfile, in this process, the top entries
by cumulative time, and the modules it imports). The machine is shared: the load average is printed
beside the figures, and the ratios, measured in the same run, are what to compare. The last line
printed is one JSON object.

    python benchmarks/startup.py [--repeats 7] [--out DIR] [--profile]
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import io
import json
import os
import pstats
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BIN = Path(sys.executable).parent
ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def _commands(out: Path) -> dict[str, list[str]]:
    return {"numpy": [sys.executable, "-c", "import numpy"],
            "import": [sys.executable, "-c", "import piezopreload"],
            "help": [str(BIN / "piezopreload"), "--help"],
            "noop_rerun": [str(BIN / "piezopreload"), "run", "--out", str(out), "--quiet", "--json"]}


def _time(command: list[str]) -> tuple[float, str]:
    t0 = time.perf_counter()
    done = subprocess.run(command, env=ENV, capture_output=True, text=True, cwd=tempfile.gettempdir())
    seconds = time.perf_counter() - t0
    if done.returncode not in (0, 4):  # 4: the study ran and missed a requirement; a rerun says so again
        raise SystemExit(f"{' '.join(command)} exited {done.returncode}: {done.stderr.strip()[-400:]}")
    return seconds, done.stdout


def _first_run(out: Path) -> None:
    """The default study into ``out`` unless it is already there (then the rerun below runs nothing)."""
    print(f"the default study into {out} (stages already up to date are not run again) ...", flush=True)
    t0 = time.perf_counter()
    done = subprocess.run([str(BIN / "piezopreload"), "run", "--out", str(out), "--quiet", "--json"], env=ENV,
                          capture_output=True, text=True)
    if done.returncode not in (0, 4):
        raise SystemExit(f"the default study failed ({done.returncode}): {done.stderr.strip()[-400:]}")
    ran = json.loads(done.stdout)["ran"]
    print(f"  {'ran ' + ', '.join(ran) if ran else 'nothing to run'} in {time.perf_counter() - t0:.1f} s", flush=True)


def _profile(out: Path) -> dict[str, object]:
    """Where a no-op rerun spends its time, in this process: the top cumulative entries and the imports."""
    before = set(sys.modules)
    profiler = cProfile.Profile()
    t0 = time.perf_counter()
    profiler.enable()
    from piezopreload.cli import main

    with contextlib.redirect_stdout(io.StringIO()):  # the run's summary: this benchmark prints its own
        main(["run", "--out", str(out), "--quiet"])
    profiler.disable()
    seconds = time.perf_counter() - t0
    text = io.StringIO()
    pstats.Stats(profiler, stream=text).sort_stats("cumulative").print_stats(25)
    print(text.getvalue())
    new = set(sys.modules) - before
    libraries = sorted({m.split(".")[0] for m in new} - set(sys.stdlib_module_names) - {"piezopreload", "__mp_main__"}
                       - {m for m in new if m.startswith("_")})
    ours = sorted(m for m in new if m.startswith("piezopreload."))
    print(f"in-process no-op rerun: {seconds:.2f} s; it imports {len(ours)} modules of ours and {', '.join(libraries)}")
    return {"profile_s": round(seconds, 3), "libraries_imported": libraries, "modules_of_ours_imported": len(ours)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7, help="timed runs of each command (default 7)")
    parser.add_argument("--out", type=Path, help="a folder that holds (or will hold) a run of the default study")
    parser.add_argument("--profile", action="store_true", help="profile a no-op rerun in this process")
    args = parser.parse_args()
    keep = tempfile.TemporaryDirectory() if args.out is None else None
    out = args.out if keep is None else Path(keep.name) / "out"
    _first_run(out)
    commands = _commands(out)
    for command in commands.values():  # warm-up: bytecode written, files in the page cache
        _time(command)
    times: dict[str, list[float]] = {name: [] for name in commands}
    for _ in range(args.repeats):
        for name, command in commands.items():
            seconds, stdout = _time(command)
            times[name].append(seconds)
            if name == "noop_rerun" and json.loads(stdout)["ran"]:
                raise SystemExit(f"the rerun ran {json.loads(stdout)['ran']}: it is not a no-op")
    median = {name: statistics.median(t) for name, t in times.items()}
    for name, t in times.items():
        print(f"{name:11s} median {median[name]:.3f} s (min {min(t):.3f}, max {max(t):.3f}) over {len(t)} runs")
    result: dict[str, object] = {
        "numpy_import_s": round(median["numpy"], 4), "import_s": round(median["import"], 4),
        "help_s": round(median["help"], 4), "noop_rerun_s": round(median["noop_rerun"], 3),
        "import_vs_numpy_ratio": round(median["import"] / median["numpy"], 3),
        "help_vs_numpy_ratio": round(median["help"] / median["numpy"], 3),
        "noop_rerun_vs_numpy_ratio": round(median["noop_rerun"] / median["numpy"], 3),
        "repeats": args.repeats, "load_average": round(os.getloadavg()[0], 2)}
    if args.profile:
        result.update(_profile(out))
    if keep is not None:
        keep.cleanup()
    print(json.dumps(result))


if __name__ == "__main__":
    main()
