"""The rig's 1 kHz loop served over OPC UA, native against Python, in the same run.

For each loop (``native``, then ``python``): ``rig serve`` on the simulated rig (the paper's
gain set and identified feedforward) for ``--seconds`` (60 by default) while an OPC UA client
in another process pushes a gain set every 2 s (two validated sets in turn) and reads the
force, the voltage and the running gain set's hash at 20 Hz. Reported per loop: missed
deadlines per 100,000 cycles, lateness percentiles, the samples lost from the log (the run
log's rows against the cycles), the push-to-switch time (the client's call until the server
shows the pushed hash running; most of it is the client's new OPC UA session), the supervisor's
share of it (the checked gain set received from the OPC UA server's process until the loop runs
it and the server shows it) and the reads done; then ``native_vs_python_missed_ratio``
(native / Python; the native count +1 over the Python count +1 where either is 0) and the
load average beside them (the machine is shared: figures under load are pessimistic).
The stall interlock runs with the limit the plant sets (rig/stall.py), the host check before
arming is made and its verdict reported (a failing host runs anyway: the benchmark measures it);
each loop's stalls (the output held longer than two periods) and its longest hold are reported
beside its misses.

The machine's own floor, measured first in the same run: ``bare_timer_...`` is the host check's
thread (``rig check``: a C thread that does nothing but wake every 1 ms on an absolute deadline,
waiting as the native loop waits, SCHED_FIFO at the loop's priority, locked memory), for the same
seconds with nothing else running: no loop can be later than the host lets this one wake
(``native_over_bare_p99_ratio``).

``--gains A.json [B.json ...] --runs N``: the other mode, the stall interlock and the host check on
validated gain sets as ``piezopreload run`` makes them. For each gain set, ``N`` runs in real time
of ``--seconds`` each (its step reference, its last level held to the end) through ``rig run``'s
path with its host check (a refusal is counted as such), then ``rig serve`` for ``--seconds``
while the client above pushes the gain set and a variant of it (its gains scaled by 0.9) every
2 s. Reported per gain set: runs completed, tripped and refused; the stalls, the longest hold and
the stall limit; the served run's status and its pushes; and the load average.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.validation import Criteria
from piezopreload.rig import native_loop
from piezopreload.rig.runlog import read_run_log
from piezopreload.rig.session import serve
from piezopreload.study import load_study, paper_study
from piezopreload.tuning.feedforward import identify_feedforward

USER, PASSWORD = "bench", "bench-password"

def bare_timer(seconds: float, priority: int = 80) -> dict:
    """The host's wake-up lateness for a C thread doing nothing else at 1 kHz: the host check's probe
    (:func:`piezopreload.rig.native_loop.probe`, the loop's own wait, priority and memory locking)."""
    late, report = native_loop.probe(1e-3, int(seconds * 1000), fifo_priority=priority)
    return {"lateness_p99_us": float(np.percentile(late, 99)) * 1e6, "lateness_max_ms": float(late.max()) * 1e3,
            "missed_per_100k": float(np.mean(late > 1e-3)) * 1e5,
            "how": f"{report['sched_fifo']}, {report['memory_locked']}"}

_CLIENT = r"""
import asyncio, json, sys, time
from asyncua import Client
from piezopreload.rig.opcua import NAMESPACE, ROOT, Credentials, push_gain_set
endpoint, seconds, docs, shas = sys.argv[1], float(sys.argv[2]), sys.argv[3:5], sys.argv[5:7]
docs = [open(p).read() for p in docs]

async def reader(stop, reads):
    c = Client(endpoint); c.set_user("bench"); c.set_password("bench-password")
    async with c:
        idx = await c.get_namespace_index(NAMESPACE)
        root = await c.nodes.objects.get_child([f"{idx}:{ROOT}"])
        nodes = [await root.get_child([f"{idx}:{n}"]) for n in ("MeasuredForce", "CommandVoltage", "GainSetSha256")]
        while not stop.is_set():
            for n in nodes:
                await n.read_value()
            reads.append(time.monotonic())
            await asyncio.sleep(0.05)

async def main():
    stop, reads, switch = asyncio.Event(), [], []
    task = asyncio.create_task(reader(stop, reads))
    t_end = time.monotonic() + seconds - 1.0
    k = 1
    while time.monotonic() + 2.0 < t_end:
        await asyncio.sleep(2.0)
        t0 = time.monotonic()
        await push_gain_set(docs[k % 2], endpoint, Credentials("bench", "bench-password"), expect_sha256=shas[k % 2])
        switch.append(time.monotonic() - t0)
        k += 1
    stop.set()
    await task
    print(json.dumps({"pushes": len(switch), "push_to_switch_s": switch, "reads": len(reads)}))

asyncio.run(main())
"""


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def one_loop(loop: str, paths: list[Path], shas: list[str], seconds: float, tmp: Path,
             accept_host: bool = True) -> dict:
    endpoint = f"opc.tcp://127.0.0.1:{_port()}/piezopreload/"
    ready, stop, out = threading.Event(), threading.Event(), {}

    def run() -> None:
        try:
            out["run"] = serve(paths[0], endpoint=endpoint, users={USER: PASSWORD}, log_dir=tmp / loop, ready=ready,
                               stop=stop, loop=loop, host_check_s=2.0, accept_host=accept_host)
        finally:
            ready.set()

    th = threading.Thread(target=run)
    th.start()
    if not ready.wait(120) or "run" in out or not th.is_alive():
        th.join()
        raise RuntimeError("the server did not start (refused by its host check, or failed)")
    client = subprocess.run([sys.executable, "-c", _CLIENT, endpoint, str(seconds), *map(str, paths), *shas],
                            capture_output=True, text=True, timeout=seconds + 120)
    stop.set()
    th.join()
    if client.returncode:
        raise RuntimeError(f"the client failed: {client.stderr[-600:]}; the server: {out['run'].summary}")
    c = json.loads(client.stdout.strip().splitlines()[-1])
    s = out["run"].summary
    t = s["timing"]
    log = read_run_log(s["log_csv"])
    cycles = int(t["cycles"])
    control_rows = int((log["mode"] == 0).sum())
    sw = np.array(c["push_to_switch_s"]) if c["push_to_switch_s"] else np.array([np.nan])
    shown = [p["switch_shown_ms"] for p in s.get("pushes", []) if "switch_shown_ms" in p] or [np.nan]
    return {
        "loop": s["loop"], "status": s["status"], "cycles": cycles, "missed": int(t["missed_deadlines"]),
        "missed_per_100k": 1e5 * t["missed_deadlines"] / max(cycles, 1),
        "lateness_p50_us": t["lateness_p50_s"] * 1e6, "lateness_p99_us": t["lateness_p99_s"] * 1e6,
        "lateness_max_ms": t["lateness_max_s"] * 1e3,
        "lost_samples": int(t.get("lost_samples", 0)) + max(cycles - control_rows, 0),
        "pushes": c["pushes"], "switches": sum(e == "gains_switched" for e in s["events"]),
        "push_to_switch_median_ms": float(np.median(sw)) * 1e3, "push_to_switch_max_ms": float(np.max(sw)) * 1e3,
        "supervisor_switch_median_ms": float(np.median(shown)), "supervisor_switch_max_ms": float(np.max(shown)),
        "reads_20Hz": c["reads"], "sched_fifo": t.get("sched_fifo"), "memory_locked": t.get("memory_locked"),
        "stalls": int(t["stalls"]), "held_max_ms": t["held_max_s"] * 1e3, "stall_limit_ms": t["stall_limit_s"] * 1e3,
        "host_check": (s.get("host_check") or {}).get("verdict"),
        "load_avg_1min_after": os.getloadavg()[0],
    }


def _held_step(gain_set: GainSet, seconds: float, path: Path) -> Path:
    """The gain set's step reference with its last level held to ``seconds``, as a time_s,force_N CSV (the file's
    last row is held for one more of its intervals)."""
    step = gain_set.reference("step")
    rows = [(float(t), float(f)) for t, f in zip(step.times_s, step.levels_N)]
    t_last = rows[-1][0] + (seconds - rows[-1][0]) / 2
    rows.append((t_last, rows[-1][1]))
    path.write_text("time_s,force_N\n" + "".join(f"{t!r},{f!r}\n" for t, f in rows))
    return path


def gain_set_runs(path: Path, runs: int, seconds: float, tmp: Path) -> dict:
    """``runs`` real-time runs of the gain set at ``path`` and one served run with pushes (see the module docstring)."""
    from dataclasses import replace

    from piezopreload.core.errors import InputError
    from piezopreload.rig.session import run

    g = GainSet.load(path)
    ref = _held_step(g, seconds, tmp / f"{path.parent.name}-reference.csv")
    results: list[dict[str, Any]] = []
    for j in range(runs):
        try:
            s = run(path, reference=str(ref), realtime=True, log_dir=tmp / f"{path.parent.name}-{j}").summary
        except InputError as exc:  # the host check refused it
            results.append({"status": "refused", "reason": str(exc)})
            continue
        t = s["timing"]
        results.append({"status": s["status"], "trip": s["trip"], "stalls": t["stalls"],
                        "held_max_ms": t["held_max_s"] * 1e3, "missed": t["missed_deadlines"],
                        "lateness_max_ms": t["lateness_max_s"] * 1e3, "host_check": s["host_check"]["verdict"],
                        "stall_limit_ms": t["stall_limit_s"] * 1e3, "load_avg_1min": os.getloadavg()[0]})
        print(f"  {path}: run {j + 1}: {s['status']}, {t['stalls']} stalls, longest hold "
              f"{t['held_max_s'] * 1e3:.2f} ms (limit {t['stall_limit_s'] * 1e3:g} ms), load {os.getloadavg()[0]:.2f}",
              file=sys.stderr)
    variant = replace(g, gains=replace(g.gains, Kc=g.gains.Kc * 0.9), content_sha256=None).save(
        tmp / f"{path.parent.name}-variant.json")
    try:
        served = one_loop("native", [path, tmp / f"{path.parent.name}-variant.json"],
                          [g.content_sha256 or "", variant.content_sha256 or ""], seconds, tmp, accept_host=False)
    except RuntimeError as exc:
        served = {"status": f"failed: {exc}"}
    done = [r for r in results if r["status"] != "refused"]
    return {"gain_set": str(path), "runs": runs, "seconds": seconds,
            "completed": sum(r["status"] == "completed" for r in results),
            "tripped": sum(r["status"] == "tripped" for r in results),
            "refused": sum(r["status"] == "refused" for r in results),
            "stalls": [r["stalls"] for r in done], "held_max_ms": max((r["held_max_ms"] for r in done), default=None),
            "stall_limit_ms": done[0]["stall_limit_ms"] if done else None,
            "trips": [r["trip"] for r in done if r["trip"]], "host_checks": [r.get("host_check") for r in results],
            "refusals": [r["reason"] for r in results if r["status"] == "refused"],
            "load_avg_1min": [r.get("load_avg_1min") for r in done],
            "serve": {k: served.get(k) for k in ("status", "pushes", "switches", "stalls", "held_max_ms", "missed",
                                                  "host_check", "load_avg_1min_after")}}


def main() -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="seconds per loop (default 60)")
    ap.add_argument("--gains", nargs="+", type=Path, help="validated gain sets: the runs mode (module docstring)")
    ap.add_argument("--runs", type=int, default=10, help="real-time runs per gain set in the runs mode (default 10)")
    args = ap.parse_args()
    if args.gains:
        load_before = os.getloadavg()
        with tempfile.TemporaryDirectory() as tmp_name:
            out = {str(p): gain_set_runs(p, args.runs, args.seconds, Path(tmp_name)) for p in args.gains}
        return {"mode": "runs", "gain_sets": out, "load_avg_before": list(load_before),
                "load_avg_after": list(os.getloadavg())}
    study = load_study(paper_study())  # the paper's rig: the default study is now the machine axis
    ff = identify_feedforward(study.plant, study.feedforward, check_range_N=None).model
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        paths, shas = [], []
        start = study.controller
        for j, gains in enumerate((start, replace(start, Kc=start.Kc * 0.8, Ti_s=start.Ti_s * 1.2))):
            g = GainSet(gains=gains, status="validated", feedforward=ff, plant=study.plant, preset=study.name,
                        references={k: study.references[k] for k in ("step", "trajectory")},
                        criteria=Criteria(band_N=study.band_N))
            g.save(tmp / f"gains{j}.json")
            paths.append(tmp / f"gains{j}.json")
            shas.append(GainSet.load(paths[-1]).content_sha256 or "")
        bare = bare_timer(args.seconds)
        print(f"  bare timer: p99 {bare['lateness_p99_us']:.1f} us, max {bare['lateness_max_ms']:.2f} ms "
              f"({bare['how']})", file=sys.stderr)
        res = {loop: one_loop(loop, paths, shas, args.seconds, tmp) for loop in ("native", "python")}
    n, p = res["native"], res["python"]
    for r in (n, p):
        print(f"{r['loop']:>6}: {r['missed']} missed of {r['cycles']} ({r['missed_per_100k']:.1f} per 100k), lateness "
              f"p50 {r['lateness_p50_us']:.1f} us p99 {r['lateness_p99_us']:.1f} us max {r['lateness_max_ms']:.2f} ms, "
              f"{r['pushes']} pushes (switch {r['push_to_switch_median_ms']:.0f} ms median, of which the supervisor's "
              f"{r['supervisor_switch_median_ms']:.1f} ms), {r['reads_20Hz']} reads, "
              f"{r['lost_samples']} lost; {r['sched_fifo']}, {r['memory_locked']}", file=sys.stderr)
    ratio = ((n["missed"] / p["missed"]) if n["missed"] and p["missed"] else (n["missed"] + 1) / (p["missed"] + 1))
    return {
        "seconds": args.seconds, "rate_Hz": 1000.0,
        "native_missed_per_100k": n["missed_per_100k"], "python_missed_per_100k": p["missed_per_100k"],
        "native_vs_python_missed_ratio": ratio,
        "native_lateness_p99_us": n["lateness_p99_us"], "python_lateness_p99_us": p["lateness_p99_us"],
        "native_lateness_max_ms": n["lateness_max_ms"], "python_lateness_max_ms": p["lateness_max_ms"],
        "bare_timer_lateness_p99_us": bare["lateness_p99_us"], "bare_timer_lateness_max_ms": bare["lateness_max_ms"],
        "bare_timer_missed_per_100k": bare["missed_per_100k"],
        "native_over_bare_p99_ratio": n["lateness_p99_us"] / max(bare["lateness_p99_us"], 1e-9),
        "native_push_to_switch_median_ms": n["push_to_switch_median_ms"],
        "python_push_to_switch_median_ms": p["push_to_switch_median_ms"],
        "native_supervisor_switch_median_ms": n["supervisor_switch_median_ms"],
        "native_supervisor_switch_max_ms": n["supervisor_switch_max_ms"],
        "python_supervisor_switch_median_ms": p["supervisor_switch_median_ms"],
        "native_lost_samples": n["lost_samples"], "python_lost_samples": p["lost_samples"],
        "native_status": n["status"], "python_status": p["status"],
        "native_stalls": n["stalls"], "python_stalls": p["stalls"], "native_held_max_ms": n["held_max_ms"],
        "python_held_max_ms": p["held_max_ms"], "stall_limit_ms": n["stall_limit_ms"],
        "host_check": [n["host_check"], p["host_check"]],
        "pushes": [n["pushes"], p["pushes"]], "switches": [n["switches"], p["switches"]],
        "reads_20Hz": [n["reads_20Hz"], p["reads_20Hz"]], "native_sched_fifo": n["sched_fifo"],
        "native_memory_locked": n["memory_locked"],
        "native_load_avg_1min_after": n["load_avg_1min_after"], "python_load_avg_1min_after": p["load_avg_1min_after"],
        "load_avg_before": list(load_before), "load_avg_after": list(os.getloadavg()),
    }


if __name__ == "__main__":
    print(json.dumps(main()))
