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
Every missed-deadline streak is let run (the interlock set out of the way) so that the two
loops are counted over the same time.

The machine's own floor, measured first in the same run: ``bare_timer_...`` is a C thread that
does nothing but wake every 1 ms on an absolute deadline (``clock_nanosleep``, SCHED_FIFO at the
loop's priority, locked memory), for the same seconds with nothing else running: no loop can be
later than the host lets this one wake (``native_over_bare_p99_ratio``).
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
from pathlib import Path

import numpy as np

from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.validation import Criteria
from piezopreload.models.controller import PIDGains
from piezopreload.rig.runlog import read_run_log
from piezopreload.rig.session import serve
from piezopreload.study import load_study, paper_study
from piezopreload.tuning.feedforward import identify_feedforward

USER, PASSWORD = "bench", "bench-password"

_BARE = r"""
#define _GNU_SOURCE
#include <pthread.h>
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/mman.h>
#include <time.h>
static long n, *late;
static long long now(void) { struct timespec t; clock_gettime(CLOCK_MONOTONIC, &t); return t.tv_sec * 1000000000LL + t.tv_nsec; }
static void* run(void* arg) {
  long long d = now() + 1000000LL;
  for (long k = 0; k < n; k++, d += 1000000LL) {
    struct timespec ts = {d / 1000000000LL, d % 1000000000LL};
    clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL);
    late[k] = (long)(now() - d);
  }
  return arg;
}
int main(int argc, char** argv) {
  n = atol(argv[1]); late = calloc(n, sizeof(long));
  int locked = mlockall(MCL_CURRENT | MCL_FUTURE) == 0;
  pthread_attr_t a; pthread_attr_init(&a);
  struct sched_param sp = {.sched_priority = atoi(argv[2])};
  pthread_attr_setinheritsched(&a, PTHREAD_EXPLICIT_SCHED);
  pthread_attr_setschedpolicy(&a, SCHED_FIFO); pthread_attr_setschedparam(&a, &sp);
  pthread_t t; int fifo = pthread_create(&t, &a, run, NULL) == 0;
  if (!fifo) pthread_create(&t, NULL, run, NULL);
  pthread_join(t, NULL);
  fprintf(stderr, "fifo %d locked %d\n", fifo, locked);
  for (long k = 0; k < n; k++) printf("%ld\n", late[k]);
  return 0;
}
"""


def bare_timer(seconds: float, tmp: Path, priority: int = 80) -> dict:
    """The host's wake-up lateness for a C thread doing nothing else at 1 kHz (module docstring)."""
    src, exe = tmp / "bare.c", tmp / "bare"
    src.write_text(_BARE)
    subprocess.run(["cc", "-O2", "-o", str(exe), str(src), "-lpthread"], check=True)
    done = subprocess.run([str(exe), str(int(seconds * 1000)), str(priority)], capture_output=True, text=True,
                          check=True)
    late = np.array(done.stdout.split(), float) * 1e-9
    return {"lateness_p99_us": float(np.percentile(late, 99)) * 1e6, "lateness_max_ms": float(late.max()) * 1e3,
            "missed_per_100k": float(np.mean(late > 1e-3)) * 1e5, "how": done.stderr.strip()}

_CLIENT = r"""
import asyncio, json, sys, time
from asyncua import Client
from piezopreload.rig.opcua import NAMESPACE, ROOT, push_gain_set
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
        await push_gain_set(docs[k % 2], endpoint, username="bench", password="bench-password",
                            expect_sha256=shas[k % 2])
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


def one_loop(loop: str, paths: list[Path], shas: list[str], seconds: float, tmp: Path) -> dict:
    endpoint = f"opc.tcp://127.0.0.1:{_port()}/piezopreload/"
    ready, stop, out = threading.Event(), threading.Event(), {}

    def run() -> None:
        out["run"] = serve(paths[0], endpoint=endpoint, users={USER: PASSWORD}, log_dir=tmp / loop, ready=ready,
                           stop=stop, loop=loop, safety={"missed_streak": 10**9})

    th = threading.Thread(target=run)
    th.start()
    if not ready.wait(60):
        raise RuntimeError("the server did not start")
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
        "load_avg_1min_after": os.getloadavg()[0],
    }


def main() -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="seconds per loop (default 60)")
    args = ap.parse_args()
    study = load_study(paper_study())  # the paper's rig: the default study is now the machine axis
    ff = identify_feedforward(study.plant, study.excitation, check_range_N=None).model
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        paths, shas = [], []
        for j, gains in enumerate((study.gains, PIDGains(Kc=study.gains.Kc * 0.8, Ti_s=study.gains.Ti_s * 1.2,
                                                         Td_s=study.gains.Td_s, Tf_s=study.gains.Tf_s,
                                                         b=study.gains.b, u_min=study.gains.u_min,
                                                         u_max=study.gains.u_max))):
            g = GainSet(gains=gains, status="validated", feedforward=ff, plant=study.plant, preset=study.name,
                        references={k: study.references[k] for k in ("step", "trajectory")},
                        criteria=Criteria(band_N=study.band_N))
            g.save(tmp / f"gains{j}.json")
            paths.append(tmp / f"gains{j}.json")
            shas.append(GainSet.load(paths[-1]).content_sha256 or "")
        bare = bare_timer(args.seconds, tmp)
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
        "pushes": [n["pushes"], p["pushes"]], "switches": [n["switches"], p["switches"]],
        "reads_20Hz": [n["reads_20Hz"], p["reads_20Hz"]], "native_sched_fifo": n["sched_fifo"],
        "native_memory_locked": n["memory_locked"],
        "native_load_avg_1min_after": n["load_avg_1min_after"], "python_load_avg_1min_after": p["load_avg_1min_after"],
        "load_avg_before": list(load_before), "load_avg_after": list(os.getloadavg()),
    }


if __name__ == "__main__":
    print(json.dumps(main()))
