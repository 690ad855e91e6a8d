"""The native loop: the Python loop's samples to the bit, the interlocks in C, the bumpless switch,
the C-ABI backend, the watchdog when the supervisor is killed, references refused before arming."""

import ctypes
import json
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from rigkit import INTERLOCK_FAULTS, write_gain_set

from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.learned import LearnedSignal
from piezopreload.cli import main
from piezopreload.core import native
from piezopreload.models.closedloop import Reference
from piezopreload.models.controller import Controller, PIDGains
from piezopreload.rig import native_loop
from piezopreload.rig.backends import CLibraryBackend, Fault, FaultInjector, SimBackend
from piezopreload.rig.executor import Executor, Safety
from piezopreload.rig.runlog import COLUMNS, RunLog, read_run_log
from piezopreload.rig.session import run as run_rig
from piezopreload.rig.watchdog import SharedDAQ

pytestmark = pytest.mark.skipif(not native_loop.available(), reason="no working C compiler: the executor runs the "
                                                                    "Python loop only")
DT = 1e-3
SAMPLE_COLUMNS = COLUMNS[:9] + ("missed", "mode")  # what does not depend on the wall clock


@pytest.fixture(scope="module")
def gains_path(tmp_path_factory, study, feedforward):
    return write_gain_set(tmp_path_factory.mktemp("gains") / "gains.json", study, feedforward)


def _run(gains_path, tmp_path, loop, faults=(), realtime=False, **safety):
    r = run_rig(gains_path, realtime=realtime, log_dir=tmp_path / loop, faults=list(faults), safety=safety, loop=loop)
    return r.to_dict(), read_run_log(r.summary["log_csv"])


def _same_samples(a, b):
    for key in SAMPLE_COLUMNS:
        np.testing.assert_array_equal(a[key], b[key], err_msg=f"column {key} differs between the loops")


def test_native_loop_gives_the_python_loops_samples(gains_path, tmp_path):
    """The paper's step back to back on both loops: every sample's number equal, NaNs in the same places."""
    rp, lp = _run(gains_path, tmp_path, "python")
    rn, ln = _run(gains_path, tmp_path, "native")
    assert rp["loop"] == "python" and rn["loop"] == "native"
    assert rn["status"] == "completed" and rn["cycles"] == rp["cycles"] == 10_001
    assert len(ln["time_s"]) == len(lp["time_s"]) > 10_001  # and the ramp down
    _same_samples(lp, ln)
    assert rn["metrics"] == rp["metrics"]
    assert rn["timing"]["lost_samples"] == 0


def test_learned_signal_plays_back_on_the_native_loop_as_on_the_python_loop(gains_path, tmp_path):
    """'rig run --learned': the signal's ff_extra reaches the native loop's compiled step at each sample; the log is
    the Python loop's (compiled step: to the bit; numpy step: to float64 rounding), and the executor says native."""
    gain_set = GainSet.load(gains_path)
    ref = gain_set.references["step"]
    n = int(round(ref.duration_s / DT)) + 1
    k = np.arange(n)
    ff = 3.0 * np.sin(2 * np.pi * k / 700.0) * (k > 50)  # volts, 0 over the first samples (the start)
    LearnedSignal(ff, ref.at(k * DT), DT, ref, gain_set.content_sha256, iteration=1).save(tmp_path / "learned.json")
    runs = {}
    for loop, step in (("native", "c"), ("python", "c"), ("python", "numpy")):
        r = run_rig(gains_path, realtime=False, log_dir=tmp_path / f"{loop}-{step}", learned=tmp_path / "learned.json",
                    loop=loop, step=step)
        runs[loop, step] = r.to_dict(), read_run_log(r.summary["log_csv"])
    rn, ln = runs["native", "c"]
    assert rn["loop"] == "native" and rn["status"] == "completed", (rn["loop"], rn.get("trip"))
    assert rn["learned"]["iteration"] == 1 and rn["timing"]["lost_samples"] == 0
    _same_samples(runs["python", "c"][1], ln)
    # the learned signal is in the feedforward term: the model's own feedforward plus ff_extra
    control = np.flatnonzero(ln["mode"] == 0)
    plain = run_rig(gains_path, realtime=False, log_dir=tmp_path / "plain", loop="native").to_dict()
    lplain = read_run_log(plain["log_csv"])
    np.testing.assert_allclose(ln["feedforward_V"][control[:51]], lplain["feedforward_V"][control[:51]], atol=0,
                               err_msg="before the signal starts the feedforward is the model's")
    assert np.max(np.abs(ln["voltage_V"][control] - lplain["voltage_V"][control])) > 0.5, "the signal does nothing"
    # the numpy step on the Python loop: the same run to the CSV's nine digits and float64 rounding
    lp = runs["python", "numpy"][1]
    assert len(lp["time_s"]) == len(ln["time_s"])
    for key in SAMPLE_COLUMNS:
        np.testing.assert_allclose(lp[key], ln[key], rtol=1e-8, atol=1e-8, equal_nan=True,
                                   err_msg=f"column {key}: the numpy step's run differs from the native loop's")


@pytest.mark.parametrize("fault, cause", INTERLOCK_FAULTS)
def test_each_interlock_acts_inside_the_native_loop_as_in_the_python_loop(gains_path, tmp_path, fault, cause):
    """The same trip (cause, time, words) and the same samples up to the end of the ramp on both loops."""
    rn, ln = _run(gains_path, tmp_path, "native", [fault], ramp_s=0.25)
    assert rn["loop"] == "native"
    assert rn["status"] == "tripped" and rn["trip"]["cause"] == cause, rn["trip"]
    rp, lp = _run(gains_path, tmp_path, "python", [fault], ramp_s=0.25)
    assert rn["trip"]["t_s"] == rp["trip"]["t_s"]
    if cause != "exception":
        assert rn["trip"]["detail"] == rp["trip"]["detail"]
    if cause != "signal":  # a signal reaches the Python loop when the interpreter gets to it
        _same_samples(lp, ln)
    ramp = ln["mode"] == 1
    assert ln["voltage_V"][ramp][-1] == 0.0 and np.all(np.diff(ln["voltage_V"][ramp]) <= 1e-9)
    np.testing.assert_allclose(np.diff(ln["time_s"]), DT, atol=1e-6, err_msg="a sample is missing from the log")
    side = json.loads(Path(rn["log_json"]).read_text())
    assert [e["event"] for e in side["events"]][-3:] == ["interlock", "ramped_down", "disarmed"]


def test_streak_of_five_missed_deadlines_stops_the_native_loop(gains_path, tmp_path):
    """A stalled backend (3 ms per read from 0.05 s): five misses in a row trip, the native loop's default limit.

    A loaded shared host stalls the whole process for 5-30 ms now and then, which trips the same
    interlock before the injected stall (twice in 34 runs here): such a run must show the
    host's stall (five cycles late by a period or more, none of them slow to compute) and is
    run again, up to three times."""
    for attempt in range(3):
        r, log = _run(gains_path, tmp_path / str(attempt), "native", [Fault("delay", 0.05, 0.003)], realtime=True,
                      ramp_s=0.05)
        assert r["trip"]["cause"] == "deadline" and r["timing"]["missed_streak_limit"] == 5
        control = log["mode"] == 0
        assert log["missed"][control][-5:].tolist() == [1] * 5
        if r["trip"]["t_s"] >= 0.05:
            break
        assert np.all(log["compute_s"][control][-5:] < 0.003), "an early trip by the injected stall"
    assert r["timing"]["missed_deadlines"] >= 5 and log["voltage_V"][-1] == 0.0
    assert 0.05 <= r["trip"]["t_s"] <= 0.05 + 6 * DT + 0.05, r["trip"]  # five late cycles after the stall began
    assert np.all(log["compute_s"][control][-5:] >= 0.003), "the trip is not the injected stall's"


def _controller(Kc=0.5, Ti_s=0.05):
    return Controller(PIDGains(Kc=Kc, Ti_s=Ti_s, Td_s=0.001, Tf_s=0.01, b=0.3), DT, None)


def test_gain_switch_is_bumpless_and_taken_at_a_cycle_boundary(study, tmp_path):
    """Mid-run push of other gains: the first command under the new gains is the last one written plus the new
    integral's increment Kc/Ti dt e (the start's closed form), and the run goes on under them."""
    old, new = _controller(), _controller(Kc=1.5, Ti_s=0.02)
    log = RunLog(tmp_path, "sw", {})
    ex = Executor(old, SimBackend(study.plant), Reference.step(25.0, 60.0, 0.05, 1.0), Safety(missed_streak=100_000),
                  realtime=True, log=log,
                  hold=True, loop="native")
    import threading

    th = threading.Thread(target=ex.run)
    th.start()
    time.sleep(0.4)
    ex.request_switch(new, {"by": "test"})
    t_asked = ex.latest[0]
    time.sleep(0.3)
    ex.stop("end of test", trip=False)
    th.join(10)
    assert not th.is_alive()
    c = log.columns()  # full precision (the CSV keeps nine digits)
    ev = {e["event"]: e for e in ex.events}
    t_sw = ev["gains_switched"]["t_s"]
    assert ev["gains_switched"]["by"] == "test" and t_asked <= t_sw <= t_asked + 0.05
    k = int(np.flatnonzero(np.isclose(c["time_s"], t_sw))[0])
    e = c["reference_N"][k] - c["measured_N"][k]
    expected = c["voltage_V"][k - 1] + new.gains.Kc / new.gains.Ti_s * DT * e
    assert c["command_V"][k] == pytest.approx(expected, abs=1e-9), "the switch jumped the command"
    # without the bumpless start the P action's change alone would have jumped it
    assert abs((new.gains.Kc - old.gains.Kc) * (0.3 * c["reference_N"][k] - c["measured_N"][k])) > 1.0
    np.testing.assert_allclose(c["p_V"][k + 1], new.gains.Kc * (0.3 * c["reference_N"][k + 1] - c["measured_N"][k + 1]),
                               atol=1e-9, err_msg="the new gains do not run after the switch")


_HW = textwrap.dedent("""
    /* a toy rig: the force follows the voltage through a first-order lag, 25 N + 0.5 N/V */
    static double force = 25.0, volts = 0.0; static long beats = 0; static int armed = 0;
    int arm(void) { force = 25.0; volts = 0.0; armed = 1; return 0; }
    int read_force(double t_s, double* f, double* ts) { *f = force; *ts = t_s; return armed ? 0 : -1; }
    int write_voltage(double v) { volts = v; force += 0.05 * (25.0 + 0.5 * v - force); return 0; }
    int disarm(void) { armed = 0; return 0; }
    int heartbeat(int level) { beats += 1; return 0; }
    long beats_seen(void) { return beats; }
    double volts_now(void) { return volts; }
""")


def test_c_abi_backend_runs_on_both_loops_with_the_same_samples(tmp_path):
    """A hardware library with arm/read_force/write_voltage/disarm/heartbeat, called from C and from Python."""
    path = native.build("pp_test_hw", _HW)
    logs = {}
    for loop in ("native", "python"):
        hw = CLibraryBackend(str(path))
        hw.lib.beats_seen.restype, hw.lib.volts_now.restype = ctypes.c_long, ctypes.c_double
        before = hw.lib.beats_seen()
        log = RunLog(tmp_path / loop, "hw", {})
        ex = Executor(_controller(), hw, Reference.step(25.0, 40.0, 0.1, 2.0), Safety(), realtime=False, log=log,
                      loop=loop)
        r = ex.run()
        assert r.ok and r.timing["loop"] == loop, r.trip
        logs[loop] = read_run_log(log.csv_path)
        assert hw.lib.beats_seen() - before == len(logs[loop]["time_s"]), "a heartbeat per cycle and ramp sample"
        assert hw.lib.volts_now() == 0.0
    _same_samples(logs["python"], logs["native"])
    control = logs["native"]["mode"] == 0
    assert logs["native"]["measured_N"][control][-1] == pytest.approx(40.0, abs=1.0), "the loop did not close"
    assert logs["native"]["voltage_V"][-1] == 0.0


def test_native_loop_falls_back_for_a_python_backend(study):
    class Plugin:
        name = "py"

        def __init__(self):
            self.inner = SimBackend(study.plant)

        def arm(self):
            self.inner.arm()

        def read_force(self, t):
            return self.inner.read_force(t)

        def write_voltage(self, v):
            self.inner.write_voltage(v)

        def disarm(self):
            pass

    ex = Executor(_controller(), Plugin(), Reference.step(25.0, 40.0, 0.1, 0.2), Safety(), realtime=False)
    assert ex.loop == "python" and "Python backend" in ex.loop_reason
    with pytest.raises(ValueError, match="native loop cannot run"):
        Executor(_controller(), Plugin(), Reference.step(25.0, 40.0, 0.1, 0.2), Safety(), loop="native")
    wrapped = FaultInjector(SimBackend(study.plant), [Fault("nan", 0.1)])
    assert Executor(_controller(), wrapped, Reference.step(25.0, 40.0, 0.1, 0.2), Safety()).loop == "native"


_KILLED = textwrap.dedent("""
    import sys
    from piezopreload.cli import main
    sys.exit(main(["rig", "run", sys.argv[1], "--log-dir", sys.argv[2], "--reference", "step",
                   "--backend-option", "watchdog_s=0.05", "--backend-option", "daq=" + sys.argv[3],
                   "--missed-streak", "100000"]))  # a loaded host's stalls must not end the run before the kill
""")


@pytest.mark.parametrize("loop", ["native", "python"])
def test_supervisor_killed_the_watchdog_cuts_the_voltage_and_the_log_is_intact(gains_path, tmp_path, loop):
    """SIGKILL to the process running the rig mid-run: the DAQ holds its last output, the watchdog process opens the
    relay within its timeout (0 V at the stacks), and the run log is whole up to its last flush."""
    daq_path = tmp_path / "daq"
    script = _KILLED.replace('"step",', f'"step", "--loop", "{loop}",')
    proc = subprocess.Popen([sys.executable, "-c", script, str(gains_path), str(tmp_path / "runs"), str(daq_path)])
    try:
        t_end = time.monotonic() + 60
        while not (daq_path.exists() and daq_path.stat().st_size and SharedDAQ(str(daq_path)).get("heartbeat") > 800):
            assert proc.poll() is None and time.monotonic() < t_end, "the run did not start"
            time.sleep(0.02)
        daq = SharedDAQ(str(daq_path))
        assert daq.get("armed") == 1 and daq.get("relay_open") == 0 and daq.get("output_V") > 1.0
        proc.send_signal(signal.SIGKILL)
        t_kill = time.monotonic()
        proc.wait(10)
        while not daq.get("relay_open"):
            assert time.monotonic() - t_kill < 5.0, "the watchdog never cut the output"
            time.sleep(0.005)
        assert daq.get("output_V") > 1.0, "the DAQ holds its last output (the relay is what cuts it)"
        assert daq.stack_V == 0.0
        timeout = daq.get("timeout_s")
        # the watchdog polls every timeout/10: it cuts within the timeout and two polls of the last beat it saw
        assert daq.get("cut_at") - daq.get("last_beat_at") <= timeout + 2 * timeout / 10 + 0.02
    finally:
        if proc.poll() is None:
            proc.kill()
    csv = next((tmp_path / "runs").glob("*.csv"))
    log = read_run_log(csv)
    assert log["time_s"][0] == 0.0 and log["time_s"][-1] > 0.5
    np.testing.assert_allclose(np.diff(log["time_s"]), DT, atol=1e-6, err_msg="the log has a hole before the kill")
    side = json.loads(csv.with_suffix(".json").read_text())
    assert side["status"] == "running"  # killed outright: the sidecar says it never ended


def test_reference_beyond_the_safe_range_is_refused_before_arming(gains_path, tmp_path, capsys):
    ref = tmp_path / "ref.csv"
    ref.write_text("time_s,force_N\n0,25\n0.5,1e9\n1.0,60\n")
    logs = tmp_path / "runs"
    assert main(["rig", "run", str(gains_path), "--fast", "--reference", str(ref), "--log-dir", str(logs)]) == 2
    err = capsys.readouterr().err
    assert f"{ref}:3: field 'force_N'" in err and "1e+09 N" in err and "before arming" in err
    assert not logs.exists() or not list(logs.iterdir()), "a refused run wrote a log"
    ref.write_text("time_s,force_N\n0,25\n0.5,140\n1.0,60\n")  # inside the interlocks, beyond the stacks' reach
    assert main(["rig", "run", str(gains_path), "--fast", "--reference", str(ref), "--log-dir", str(logs)]) == 2
    assert "beyond what the gain set's plant reaches" in capsys.readouterr().err


@pytest.mark.parametrize("argv, words", [
    (["rig", "run", "G", "--inject", "bogus@1"], "unknown fault 'bogus'"),
    (["rig", "run", "G", "--missed-streak", "0"], "--missed-streak"),
    (["rig", "run", "G", "--loop", "fortran"], "--loop"),
    (["identify", "--operators", "100000"], "or at most 5368 operators"),  # the memory bound is the tighter
])
def test_bad_arguments_exit_2_with_what_is_allowed(gains_path, tmp_path, capsys, argv, words):
    argv = [str(gains_path) if a == "G" else a for a in argv]
    assert main([*argv, *(["--log-dir", str(tmp_path)] if argv[0] == "rig" else [])]) == 2
    err = capsys.readouterr().err
    assert words in err and err.startswith("error: "), err


def test_interlock_limits_come_from_safety_once(study):
    """The native loop reads every limit of Safety; a changed Safety changes what the C loop checks."""
    s = Safety(force_max_N=90.0, missed_streak=None)
    ex = Executor(_controller(), SimBackend(study.plant), Reference.step(25.0, 40.0, 0.1, 0.2), s, realtime=False)
    loop = ex._native_setup()
    assert loop._L.force_max == 90.0 and loop._L.force_low == s.force_low_N and loop._L.missed_streak == 5
    assert s.streak_limit("python") == 50



def test_operators_beyond_the_memory_bound_are_refused_before_allocating(monkeypatch, capsys):
    """With the bound at ten operators' matrix for the shipped record, 40 operators are refused by it."""
    from piezopreload.tuning import identification

    monkeypatch.setattr(identification, "MAX_MATRIX_BYTES", 8 * 50_001 * 10)
    assert main(["identify", "--operators", "40"]) == 2
    err = capsys.readouterr().err
    assert "--operators 40: at most 10" in err and "GiB" in err, err
