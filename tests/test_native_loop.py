"""The native loop: the Python loop's samples and events to the bit (one interlock table, one fault script),
the interlocks in C, the stall interlock on an injected clock, the bumpless switch, the C-ABI backend, the
watchdog when the supervisor is killed, references refused before arming."""

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
from rigkit import INTERLOCK_FAULTS, STALL_LIMIT_S, STALL_SCRIPT, STALL_SCRIPT_STALLS, events, write_gain_set

from piezopreload.artifacts.gainset import GainSet
from piezopreload.artifacts.learned import LearnedSignal
from piezopreload.cli import main
from piezopreload.core import native
from piezopreload.models.closedloop import Reference
from piezopreload.models.controller import Controller, PIDGains
from piezopreload.rig import interlocks, native_loop
from piezopreload.rig.backends import CLibraryBackend, Fault, FaultInjector, SimBackend
from piezopreload.rig.executor import Executor, Safety
from piezopreload.rig.native_run import NativeRun
from piezopreload.rig.runlog import COLUMNS, RunLog, read_run_log
from piezopreload.rig.session import run as run_rig
from piezopreload.rig.watchdog import SharedDAQ

pytestmark = pytest.mark.skipif(not native_loop.available(), reason="no working C compiler: the executor runs the "
                                                                    "Python loop only")
DT = 1e-3
#: back to back, the loops run on a virtual clock: every column, the timing's too, is the same on both
SAMPLE_COLUMNS = COLUMNS


@pytest.fixture(scope="module")
def gains_path(tmp_path_factory, study, feedforward):
    return write_gain_set(tmp_path_factory.mktemp("gains") / "gains.json", study, feedforward)


def _run(gains_path, tmp_path, loop, faults=(), realtime=False, **safety):
    r = run_rig(gains_path, realtime=realtime, log_dir=tmp_path / loop, faults=list(faults), safety=safety, loop=loop,
                host_check_s=0.2)
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


@pytest.mark.slow
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
    """The same trip (cause, time, words, voltage), the same samples and the same event log on both loops."""
    rn, ln = _run(gains_path, tmp_path, "native", [fault], ramp_s=0.25, stall_limit_s=STALL_LIMIT_S)
    assert rn["loop"] == "native"
    assert rn["status"] == "tripped" and rn["trip"]["cause"] == cause, rn["trip"]
    rp, lp = _run(gains_path, tmp_path, "python", [fault], ramp_s=0.25, stall_limit_s=STALL_LIMIT_S)
    assert rp["loop"] == "python" and rn["trip"] == rp["trip"]
    _same_samples(lp, ln)
    assert events(rn["log_json"]) == events(rp["log_json"]), "the loops' event logs differ"
    ramp = ln["mode"] == 1
    assert ln["voltage_V"][ramp][-1] == 0.0 and np.all(np.diff(ln["voltage_V"][ramp]) <= 1e-9)
    np.testing.assert_allclose(np.diff(ln["time_s"]), DT, atol=1e-6, err_msg="a sample is missing from the log")
    names = [e["event"] for e in events(rn["log_json"])]
    assert names[-3:] == ["interlock", "ramped_down", "disarmed"] and "traceback" not in names


def test_one_fault_script_gives_both_loops_the_same_stalls_samples_and_events(gains_path, tmp_path):
    """STALL_SCRIPT on the virtual clock: the stalls shorter than the limit are counted and logged with the time the
    output was held, the longer one trips, and the two loops' logs are the same, sample for sample, event for event."""
    rn, ln = _run(gains_path, tmp_path, "native", STALL_SCRIPT, stall_limit_s=STALL_LIMIT_S)
    rp, lp = _run(gains_path, tmp_path, "python", STALL_SCRIPT, stall_limit_s=STALL_LIMIT_S)
    _same_samples(lp, ln)
    ev = events(rn["log_json"])
    assert ev == events(rp["log_json"])
    stalls = [(e["t_s"], e["held_s"]) for e in ev if e["event"] == "stall"]
    np.testing.assert_allclose(stalls, STALL_SCRIPT_STALLS, rtol=0, atol=1e-12, err_msg="the stalls logged")
    for r in (rn, rp):
        assert r["trip"]["cause"] == "stall" and r["trip"]["t_s"] == 1.0
        assert r["trip"]["detail"] == f"the output was held 0.2010 s without an update (limit {STALL_LIMIT_S:g} s)"
        assert r["timing"]["stalls"] == len(STALL_SCRIPT_STALLS) and r["timing"]["held_max_s"] == pytest.approx(0.201)
        assert r["metrics"] is None, "a tripped run reports step metrics"
    # the trip's voltage is the one held when it tripped: the last command written before t = 1.0 s (the CSV keeps
    # nine digits)
    k = int(np.flatnonzero(ln["mode"] == 2)[0])
    assert ln["voltage_V"][k] == ln["voltage_V"][k - 1] > 5.0
    assert rn["trip"]["voltage_V"] == pytest.approx(ln["voltage_V"][k], rel=1e-8)
    interlock = next(e for e in ev if e["event"] == "interlock")
    assert interlock["voltage_V"] == rn["trip"]["voltage_V"], "the interlock event's voltage is not the held one"


@pytest.mark.realtime
def test_a_long_stall_trips_a_realtime_run_and_a_short_one_is_counted(gains_path, tmp_path):
    """In real time on the native loop: a backend read stalled 20 ms is counted, one stalled 250 ms trips (limit
    100 ms). The run could trip earlier only if the host itself stalled the loop for 100 ms in its first 0.6 s; the
    stalls the host adds are counted beside the injected ones."""
    faults = [Fault("delay", 0.3, 0.02, 0.001), Fault("delay", 0.6, 0.25, 0.001)]
    r, log = _run(gains_path, tmp_path, "native", faults, realtime=True, stall_limit_s=STALL_LIMIT_S, ramp_s=0.05)
    assert r["trip"]["cause"] == "stall" and r["trip"]["t_s"] == 0.6, r["trip"]
    ev = events(r["log_json"])
    short = [e for e in ev if e["event"] == "stall" and e["t_s"] == 0.3]
    assert short and short[0]["held_s"] >= 0.02, "the short stall was not counted"
    long = next(e for e in ev if e["event"] == "stall" and e["t_s"] == 0.6)
    assert long["held_s"] >= 0.25 and r["timing"]["held_max_s"] >= 0.25
    assert r["timing"]["stalls"] >= 2 and log["voltage_V"][-1] == 0.0


def _controller(Kc=0.5, Ti_s=0.05):
    return Controller(PIDGains(Kc=Kc, Ti_s=Ti_s, Td_s=0.001, Tf_s=0.01, b=0.3), DT, None)


def _until(predicate, what, timeout_s=60.0):
    """Wait for the loop's own progress (its timeline, not the wall clock); fail after a generous timeout."""
    t_end = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < t_end, f"the loop never got to {what}"
        time.sleep(0.01)


def test_gain_switch_is_bumpless_and_taken_at_a_cycle_boundary(study, tmp_path):
    """Mid-run push of other gains: the first command under the new gains is the last one written plus the new
    integral's increment Kc/Ti dt e (the start's closed form), and the run goes on under them. Back to back on the
    virtual clock: the test waits for the loop's timeline, not for the wall clock."""
    import threading

    old, new = _controller(), _controller(Kc=1.5, Ti_s=0.02)
    log = RunLog(tmp_path, "sw")
    ex = Executor(old, SimBackend(study.plant), Reference.step(25.0, 60.0, 0.05, 1.0), Safety(),
                  realtime=False, log=log, hold=True, loop="native")
    th = threading.Thread(target=ex.run)
    th.start()
    _until(lambda: ex.latest[0] > 0.4, "t = 0.4 s")
    t_before = ex.latest[0]
    ex.request_switch(new, {"by": "test"})
    _until(lambda: not ex.switch_pending and ex.latest[0] > t_before + 0.3, "the switch and 0.3 s after it")
    ex.stop("end of test", trip=False)
    th.join(30)
    assert not th.is_alive()
    c = log.columns()  # full precision (the CSV keeps nine digits)
    ev = {e["event"]: e for e in ex.events}
    t_sw = ev["gains_switched"]["t_s"]
    assert ev["gains_switched"]["by"] == "test" and t_sw >= t_before
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
        log = RunLog(tmp_path / loop, "hw")
        ex = Executor(_controller(), hw, Reference.step(25.0, 40.0, 0.1, 2.0), Safety(), realtime=False, log=log,
                      loop=loop)
        r = ex.run()
        assert r.ok and r.timing.loop == loop, r.trip
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


# the watchdog's timeout: long enough that a loaded 2-core host's scheduling (the Python loop late by tens of ms, a
# real stall the watchdog rightly cuts) does not open the relay before the kill this test is about
_KILLED = textwrap.dedent("""
    import sys
    from piezopreload.cli import main
    sys.exit(main(["rig", "run", sys.argv[1], "--log-dir", sys.argv[2], "--reference", "step",
                   "--backend-option", "watchdog_s=0.25", "--backend-option", "daq=" + sys.argv[3],
                   "--host-check-s", "0.2", "--accept-host"]))
""")


@pytest.mark.slow
@pytest.mark.realtime
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
        # never before the timeout (when after it is the watchdog's decision, tested on an injected clock below;
        # here the host's scheduling adds to it)
        assert daq.get("cut_at") - daq.get("last_beat_at") > daq.get("timeout_s")
    finally:
        if proc.poll() is None:
            proc.kill()
    csv = next((tmp_path / "runs").glob("*.csv"))
    log = read_run_log(csv)
    assert log["time_s"][0] == 0.0 and log["time_s"][-1] > 0.5
    np.testing.assert_allclose(np.diff(log["time_s"]), DT, atol=1e-6, err_msg="the log has a hole before the kill")
    side = json.loads(csv.with_suffix(".json").read_text())
    assert side["status"] == "running"  # killed outright: the sidecar says it never ended


def test_the_watchdog_opens_the_relay_one_poll_after_its_timeout_on_an_injected_clock():
    """The watchdog's decision: polled every timeout/10 on an injected clock, it keeps the relay closed while the
    heartbeat changes or the rig is disarmed, and opens it at the first poll more than the timeout after the last
    beat it saw: within the timeout and one poll."""
    from piezopreload.rig.watchdog import Watch

    timeout, poll = 0.05, 0.005
    watch = Watch(timeout, beat=0, now=0.0)
    beats = {round(k * poll, 6): k for k in range(1, 41)}  # beating until t = 0.2 s
    cut_at = None
    for k in range(1, 200):
        now = round(k * poll, 6)
        if watch.poll(beats.get(now, 40), armed=True, now=now):
            cut_at = now
            break
    assert cut_at is not None and timeout < cut_at - 0.2 <= timeout + poll, cut_at
    idle = Watch(timeout, beat=0, now=0.0)
    assert not any(idle.poll(0, armed=False, now=k * poll) for k in range(1, 200)), "a disarmed rig was cut"


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
    (["rig", "run", "G", "--stall-limit-s", "0"], "--stall-limit-s"),
    (["rig", "run", "G", "--force-max-N", "-5"], "--force-max-N"),
    (["rig", "run", "G", "--loop", "fortran"], "--loop"),
    (["identify", "--operators", "100000"], "or at most 5368 operators"),  # the memory bound is the tighter
])
def test_bad_arguments_exit_2_with_what_is_allowed(gains_path, tmp_path, capsys, argv, words):
    argv = [str(gains_path) if a == "G" else a for a in argv]
    assert main([*argv, *(["--log-dir", str(tmp_path)] if argv[0] == "rig" else [])]) == 2
    err = capsys.readouterr().err
    assert words in err and err.startswith("error: "), err


def test_the_native_loop_runs_the_one_interlock_table(study):
    """The C loop receives the table's rows with Safety's numbers, and its codes come from the same table: a changed
    limit changes what C tests, and the C source names no limit, cause or order of its own."""
    s = Safety(force_max_N=90.0, stall_limit_s=0.02)
    ex = Executor(_controller(), SimBackend(study.plant), Reference.step(25.0, 40.0, 0.1, 0.2), s, realtime=False)
    loop = NativeRun(ex)._setup()
    got = [(r.stage, r.quantity, r.test, r.cause, r.lo, r.hi) for r in loop._L.interlocks[:loop._L.n_interlocks]]
    np.testing.assert_array_equal(np.array(got), np.array(interlocks.rows(s)), err_msg="C runs other rows")
    assert dict(zip((i.cause for i in interlocks.INTERLOCKS), got))["force_high"][4] == 90.0
    assert native_loop.source().startswith(interlocks.c_defines())
    c = Path(native_loop.__file__).with_name("native_loop.c").read_text()
    for limit in ("force_max", "force_low", "sensor_min", "stale_after", "stall_limit", "missed_streak"):
        assert limit not in c, f"native_loop.c names '{limit}': the limits are the table's"


def test_operators_beyond_the_memory_bound_are_refused_before_allocating(monkeypatch, capsys):
    """With the bound at ten operators' matrix for the shipped record, 40 operators are refused by it."""
    from piezopreload.tuning import identification

    monkeypatch.setattr(identification, "MAX_MATRIX_BYTES", 8 * 50_001 * 10)
    assert main(["identify", "--operators", "40"]) == 2
    err = capsys.readouterr().err
    assert "--operators 40: at most 10" in err and "GiB" in err, err
