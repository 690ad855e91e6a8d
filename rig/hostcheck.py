"""The host check: how late this host wakes the loop, against the loop's budget and its stall limit.

A bare thread waits as the loop waits (the native loop's: ``clock_nanosleep`` to absolute
deadlines at the loop's ``SCHED_FIFO`` priority with locked memory where permitted; the
Python loop's: a sleep and a spin in the interpreter) at the loop's rate for ``seconds``, and
records how late each wake-up came. Nothing else runs in it: what it measures is the host's
part of every cycle's lateness. Beside it, the controller step's compute time is measured
(the compiled step, timed in C, or the numpy step), and the host's facts that matter for a
real-time loop are read (:func:`host_facts`).

The verdict (:func:`judge`) passes when both hold:

* **rate**: the p99 lateness of the wake-ups that waited for their deadline, plus the step's
  p99 compute time, fits in the period: at most 1 % of the host's wake-ups from a wait would
  miss their deadline (a missed deadline is counted, not tripped, but a loop that misses more
  than that does not run at its rate). The wake-ups right after one later than a period do not
  wait (their deadlines have passed: the loop catches up at once); they belong to that stall,
  which the next criterion judges, and would otherwise count one stall of 15 ms as 15 misses;
* **stall**: the latest wake-up plus a period plus the step's longest compute time stays
  below the stall limit (:mod:`piezopreload.rig.stall`): no stall the check saw would have
  tripped the run. Without a stall limit (no gain set given), this criterion is not judged.

``rig run --realtime`` and ``rig serve`` make this check for a few seconds before arming and
refuse a host that fails it unless ``--accept-host``.
"""

from __future__ import annotations

import math
import os
import platform
import threading
import time
from pathlib import Path

import numpy as np

from piezopreload.artifacts.hostcheck import BIN_EDGES_S, Criterion, HostCheck, HostFacts
from piezopreload.core.progress import ProgressLike, say_of
from piezopreload.models.controller import Controller, PIDGains
from piezopreload.rig import native_loop
from piezopreload.rig.clock import MonotonicClock, to_ns
from piezopreload.rig.compiled import controller_step

__all__ = ["check_host", "host_facts", "judge", "waited", "RATE_QUANTILE", "STEP_CALLS"]

#: the rate criterion's quantile: at most 1 - RATE_QUANTILE of the cycles may miss their deadline
RATE_QUANTILE = 0.99
#: calls of the controller step timed
STEP_CALLS = 2000


def _read(path: str) -> str | None:
    try:
        return Path(path).read_text(encoding="utf-8", errors="replace").strip()
    except OSError:
        return None


def _governor() -> str:
    found = {g for g in (_read(f"/sys/devices/system/cpu/cpu{j}/cpufreq/scaling_governor")
                         for j in range(os.cpu_count() or 1)) if g}
    if not found:
        return "no CPU frequency scaling visible (a virtual machine, or fixed by the firmware)"
    if found == {"performance"}:
        return "performance"
    return f"{', '.join(sorted(found))} (not 'performance': the clock may ramp up after each sleep)"


def _virtualisation() -> str:
    cpuinfo = _read("/proc/cpuinfo") or ""
    vendor = " ".join(x for x in (_read("/sys/class/dmi/id/sys_vendor"), _read("/sys/class/dmi/id/product_name")) if x)
    vm = "hypervisor" in cpuinfo.split()
    container = Path("/.dockerenv").exists() or "docker" in (_read("/proc/1/cgroup") or "")
    parts = []
    if vm:
        parts.append(f"a virtual machine ({vendor or 'the CPU reports a hypervisor'})")
    if container:
        parts.append("in a container")
    return ", ".join(parts) if parts else "bare metal (no hypervisor flag)"


def _isolated() -> str:
    isolated = _read("/sys/devices/system/cpu/isolated") or ""
    cmdline = (_read("/proc/cmdline") or "").split()
    nohz = next((a.split("=", 1)[1] for a in cmdline if a.startswith("nohz_full=")), "")
    if not isolated and not nohz:
        return "none (the loop shares its CPU with everything else)"
    return f"isolated {isolated or '-'}, nohz_full {nohz or '-'}"


def host_facts(report: dict[str, str]) -> HostFacts:
    """What this host is for a real-time loop; ``report`` is what the check's thread was granted."""
    version = platform.version()
    realtime = _read("/sys/kernel/realtime") == "1" or "PREEMPT_RT" in version
    preemption = next((p for p in ("PREEMPT_RT", "PREEMPT_DYNAMIC", "PREEMPT") if p in version), "none stated")
    return HostFacts(kernel=f"{platform.system()} {platform.release()}", rt_kernel=realtime, preemption=preemption,
                     sched_fifo=report.get("sched_fifo", "SCHED_FIFO: not asked"),
                     memory_locked=report.get("memory_locked", "mlockall: not asked"), cpu_governor=_governor(),
                     virtualisation=_virtualisation(), isolated_cpus=_isolated(), cpus=os.cpu_count() or 1)


def _findings(facts: HostFacts) -> tuple[str, ...]:
    out = []
    if not facts.rt_kernel:
        out.append(f"not a real-time kernel (preemption: {facts.preemption}): a wake-up can wait for a kernel section; "
                   "a PREEMPT_RT kernel bounds that")
    if "yes" not in facts.sched_fifo:
        out.append(f"{facts.sched_fifo}: the loop competes with every other thread")
    if "yes" not in facts.memory_locked:
        out.append(f"{facts.memory_locked}: a page fault can stall the loop")
    if "virtual machine" in facts.virtualisation:
        out.append("a virtual machine: the hypervisor can stop the whole machine for milliseconds, which no "
                   "priority inside it prevents")
    if not facts.cpu_governor.startswith("performance"):
        out.append(f"CPU frequency: {facts.cpu_governor}")
    if facts.isolated_cpus.startswith("none"):
        out.append("no isolated CPU: 'isolcpus=' and 'nohz_full=' on the kernel's command line keep a CPU for the loop")
    return tuple(out)


def _probe_python(dt_s: float, n: int) -> np.ndarray:
    """The Python loop's wait in a thread of the interpreter, ``n`` times."""
    late = np.zeros(n)
    dt_ns = to_ns(dt_s)

    def body() -> None:
        t0 = MonotonicClock.now() + dt_ns
        for k in range(n):
            deadline = t0 + k * dt_ns
            late[k] = (MonotonicClock.wait(deadline) - deadline) * 1e-9

    thread = threading.Thread(target=body, name="host-check")
    thread.start()
    thread.join()
    return late


def _step_times(controller: Controller, loop: str) -> np.ndarray:
    """The controller step's compute time per call (s): from C for the native loop, from Python otherwise."""
    if loop == "native":
        return native_loop.time_step(controller, STEP_CALLS)
    step = controller_step(controller)
    step.start(50.0, 50.0, 0.0)
    out = np.zeros(STEP_CALLS)
    for k in range(STEP_CALLS):
        t = time.perf_counter_ns()
        step.step(50.0, 50.0 + 1e-3 * (k & 7))
        out[k] = (time.perf_counter_ns() - t) * 1e-9
    return out


def waited(late: np.ndarray, period_s: float) -> np.ndarray:
    """The lateness of the wake-ups that waited for their deadline: the first, and each after one less than a period
    late (after a later one the deadline has passed already and the thread runs on at once)."""
    return np.concatenate([late[:1], late[1:][late[:-1] < period_s]])


def judge(late: np.ndarray, step: np.ndarray, period_s: float, stall_limit_s: float | None) -> tuple[Criterion, ...]:
    """The criteria of the module docstring, with their numbers."""
    p99, step_p99 = float(np.quantile(waited(late, period_s), RATE_QUANTILE)), float(np.quantile(step, RATE_QUANTILE))
    q = f"p{100 * RATE_QUANTILE:g}"
    rate = Criterion("rate", p99 + step_p99 <= period_s,
                     f"{q} lateness of the wake-ups that waited {p99 * 1e6:.0f} us + step {q} {step_p99 * 1e6:.1f} us "
                     f"{'<=' if p99 + step_p99 <= period_s else '>'} the period {period_s * 1e6:.0f} us")
    if stall_limit_s is None:
        return (rate,)
    held = float(late.max()) + period_s + float(step.max())
    stall = Criterion("stall", held < stall_limit_s,
                      f"longest hold seen {held * 1e3:.2f} ms (the latest wake-up + a period + the longest step) "
                      f"{'<' if held < stall_limit_s else '>='} the stall limit {stall_limit_s * 1e3:.1f} ms")
    return rate, stall


def check_host(*, rate_Hz: float, seconds: float, controller: Controller | None = None,
               stall_limit_s: float | None = None, loop: str = "native", priority: int = 80,
               progress: ProgressLike | None = None) -> HostCheck:
    """Measure this host's wake-up lateness for ``seconds`` at ``rate_Hz`` and judge it (see the module docstring).

    ``controller``: the step whose compute time is the budget's other part (None: a PID step
    without feedforward stands in); ``loop``: ``native`` (the C thread, where a compiler works)
    or ``python``; ``stall_limit_s``: the run's (None: not judged).
    """
    if not (math.isfinite(rate_Hz) and rate_Hz > 0 and math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"the check needs a rate > 0 and seconds > 0, got {rate_Hz!r} Hz and {seconds!r} s")
    if loop == "native" and not native_loop.available():
        loop = "python"
    dt = 1.0 / rate_Hz
    what = "the gain set's compiled step"
    if controller is None:
        controller = Controller(PIDGains(Kc=1.0, Ti_s=0.1, Td_s=1e-3, Tf_s=1e-2), dt, None)
        what = "a PID step without feedforward (no gain set given)"
    n = max(10, int(round(seconds * rate_Hz)))
    if (say := say_of(progress)) is not None:
        say(f"checking this host: {n} wake-ups at {rate_Hz:g} Hz on the {loop} loop's wait ...")
    if loop == "native":
        late, report = native_loop.probe(dt, n, fifo_priority=priority)
    else:
        late, report = _probe_python(dt, n), {}
    step = _step_times(controller, loop)
    facts = host_facts(report)
    counts, _ = np.histogram(np.clip(late, 0.0, None), bins=np.asarray(BIN_EDGES_S[:-1] + (1e300,)))
    budget = dt - float(np.quantile(step, RATE_QUANTILE))
    return HostCheck(
        seconds=n * dt, rate_Hz=rate_Hz, samples=n, lateness_p50_s=float(np.median(late)),
        lateness_p99_s=float(np.quantile(late, 0.99)), lateness_p999_s=float(np.quantile(late, 0.999)),
        lateness_max_s=float(late.max()), waited_p99_s=float(np.quantile(waited(late, dt), RATE_QUANTILE)),
        missed=int(np.sum(late > budget)),
        step_p99_s=float(np.quantile(step, 0.99)), step_max_s=float(step.max()),
        step_what=f"{what}, {'timed in C' if loop == 'native' else 'timed in Python'}", budget_s=budget,
        stall_limit_s=stall_limit_s, histogram_counts=tuple(int(c) for c in counts), facts=facts,
        criteria=judge(late, step, dt, stall_limit_s), findings=_findings(facts), lateness_s=late)
