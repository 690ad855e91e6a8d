"""The controller step's cost per call against simple_pid, and the rig loop's timing at 1 kHz.

1. Time per call of our full controller step (40-operator inverse P-I feedforward + PID, as the
   rig executor runs it: compiled C through ctypes, or numpy where no compiler works) against
   ``simple_pid.PID.__call__`` (a PID alone), on the same 20,000 measurements, same run.
   ``step_time_ratio`` = ours / simple_pid; target <= 3. The numpy step is timed too.
2. The executor on the simulated backend at 1 kHz for 10 s in real time (the paper's step held):
   missed deadlines and lateness percentiles, on the loop the executor chooses (``loop``: the
   native loop where a C compiler works; ``benchmarks/rig_loop.py`` compares the two loops).
"""

from __future__ import annotations

import json
import sys
import tempfile
import timeit
from dataclasses import asdict
from pathlib import Path

import numpy as np
from simple_pid import PID

from piezopreload.models.closedloop import Reference
from piezopreload.models.controller import Controller, PIDGains
from piezopreload.rig.backends import SimBackend
from piezopreload.rig.compiled import PythonStep, controller_step
from piezopreload.rig.executor import Executor, Safety
from piezopreload.study import load_study, paper_study
from piezopreload.tuning.feedforward import identify_feedforward


def per_call(fn, repeat: int = 5) -> float:
    return min(timeit.repeat(fn, number=1, repeat=repeat))


def main() -> dict:
    study = load_study(paper_study())
    model = identify_feedforward(study.plant, study.feedforward, check_range_N=None).model
    assert model.n_operators == 40
    gains = PIDGains(Kc=0.5, Ti_s=0.05, Td_s=0.001, Tf_s=0.01, b=0.3)
    controller = Controller(gains, 1e-3, model.inverse())
    n = 20_000
    rng = np.random.default_rng(0)
    sp = (60.0 + 30.0 * np.sin(np.arange(n) * 2e-3)).tolist()  # the setpoint moves: the P-I works every call
    pv = (np.array(sp) - 0.5 + 0.25 * rng.standard_normal(n)).tolist()

    ours = controller_step(controller)
    ours.start(sp[0], pv[0], 0.0)
    numpy_step = PythonStep(controller)
    numpy_step.start(sp[0], pv[0], 0.0)
    pid = PID(gains.Kc, gains.Kc / gains.Ti_s, gains.Kc * gains.Td_s, setpoint=60.0, sample_time=None,
              output_limits=(0.0, 110.0))
    pairs = list(zip(sp, pv))

    def run_ours():
        step = ours.step
        for s, y in pairs:
            step(s, y)

    def run_numpy():
        step = numpy_step.step
        for s, y in pairs[:2000]:
            step(s, y)

    def run_pid():
        for _, y in pairs:
            pid(y, dt=1e-3)

    t_ours = per_call(run_ours) / n
    t_pid = per_call(run_pid) / n
    t_numpy = per_call(run_numpy, 3) / 2000
    print(f"controller step ({ours.kind}, 40-operator inverse P-I + PID): {t_ours * 1e6:.2f} us per call",
          file=sys.stderr)
    print(f"simple_pid.PID.__call__ (PID alone):                        {t_pid * 1e6:.2f} us per call",
          file=sys.stderr)
    print(f"controller step, numpy path:                                {t_numpy * 1e6:.2f} us per call",
          file=sys.stderr)

    # the loop at 1 kHz for 10 s, real time, on the simulated rig
    ref = Reference.step(25.0, 60.0, 0.5, 10.0)
    with tempfile.TemporaryDirectory() as tmp:
        from piezopreload.rig.runlog import RunLog

        log = RunLog(Path(tmp), "bench")
        # the stall interlock out of the way: the run is timed whole, stalls and all
        ex = Executor(controller, SimBackend(study.plant), ref, Safety(stall_limit_s=1e9), realtime=True, log=log)
        result = ex.run()
    t = asdict(result.timing)
    print(f"{t['loop']} loop at 1 kHz for 10 s ({result.status}): {t['missed_deadlines']} missed "
          f"deadlines of {t['cycles']}, lateness p50 {t['lateness_p50_s'] * 1e6:.1f} us, "
          f"p99 {t['lateness_p99_s'] * 1e6:.1f} us, max {t['lateness_max_s'] * 1e3:.2f} ms", file=sys.stderr)
    return {
        "controller_step": ours.kind,
        "step_us": t_ours * 1e6, "simple_pid_us": t_pid * 1e6, "numpy_step_us": t_numpy * 1e6,
        "step_time_ratio": t_ours / t_pid, "numpy_step_time_ratio": t_numpy / t_pid,
        "loop": t["loop"], "loop_status": result.status, "loop_cycles": t["cycles"],
        "loop_missed_deadlines": t["missed_deadlines"], "loop_lateness_p50_us": t["lateness_p50_s"] * 1e6,
        "loop_lateness_p99_us": t["lateness_p99_s"] * 1e6, "loop_lateness_max_ms": t["lateness_max_s"] * 1e3,
        "loop_period_std_us": t["period_std_s"] * 1e6,
    }


if __name__ == "__main__":
    print(json.dumps(main()))
