"""``rig run``'s text is read from the run's sidecar record (``RigRun.record``, a :class:`RigRunRecord`), not from the
``--json`` summary's string keys: on the same run it prints what the summary-reading printer printed, line for line,
and ``--json`` keeps its keys."""

import contextlib
import io
import json
from dataclasses import replace

import pytest
from rigkit import write_gain_set

from piezopreload.cli import main
from piezopreload.cli._common import fmt
from piezopreload.cli.rig import _print_rig_run
from piezopreload.rig.backends import parse_fault
from piezopreload.rig.session import run as run_rig

#: the keys ``rig run --json`` printed before the printer read the record (rig/session.py's summary)
JSON_KEYS = {"status", "exit_code", "trip", "cycles", "controller_step", "loop", "timing", "clamped_cycles", "metrics",
             "log_csv", "log_json", "gain_set", "gain_set_sha256", "feedforward_sha256", "backend", "reference",
             "rate_Hz", "realtime", "interlocks", "interlock_sources", "stall_limit", "host_check", "host_accepted",
             "events"}


def _summary_printer(s):
    """The printer as it was: every figure read from the ``--json`` summary by its key (the reference)."""
    t = s["timing"]
    print(f"{s['status']}: {s['cycles']} cycles at {s['rate_Hz']:g} Hz on '{s['backend']}' "
          f"({'real time' if s['realtime'] else 'back to back'}), controller step in {s['controller_step']}, "
          f"{s.get('loop') or 'python'} loop")
    if s["trip"]:
        trip = s["trip"]
        print(f"stopped by interlock '{trip['cause']}' at t = {trip['t_s']:.3f} s with {trip['voltage_V']:.4g} V held: "
              f"{trip['detail']}")
    m = s["metrics"]
    if m is not None and m.get("settling_s") is not None:
        print(f"step: rise {fmt(m['rise_s'], ' s')}, peak {fmt(m['peak_s'], ' s')}, "
              f"settling {fmt(m['settling_s'], ' s')}, overshoot {fmt(m['overshoot_N'], ' N')}; "
              f"tracking RMS {m['tracking_rms_N']:.3g} N")
    elif m is not None and m.get("tracking_rms_N") is not None:
        print(f"tracking RMS {m['tracking_rms_N']:.3g} N, largest error {m['tracking_max_N']:.3g} N")
    lim, src = s["interlocks"], s["interlock_sources"]
    print(f"interlocks: force {lim['bolt_preload_N'] - lim['force_low_margin_N']:g}..{lim['force_max_N']:g} N "
          f"(force_max_N from {src['force_max_N']}); stall limit {lim['stall_limit_s'] * 1e3:g} ms "
          f"(from {src['stall_limit_s']})")
    print(f"timing: {t['missed_deadlines']} missed deadlines, {t['stalls']} stalls (longest hold "
          f"{t['held_max_s'] * 1e3:.2f} ms), lateness p99 {t['lateness_p99_s'] * 1e6:.0f} us, max "
          f"{t['lateness_max_s'] * 1e3:.2f} ms, {t.get('lost_samples', 0)} samples lost"
          + (f"; {t['sched_fifo']}; {t['memory_locked']}" if t.get("sched_fifo") else ""))
    if s.get("host_check"):
        h = s["host_check"]
        print(f"host check: {h['verdict']}{' (run anyway: --accept-host)' if h['verdict'] == 'fail' else ''}; "
              f"lateness p99 {h['lateness_p99_s'] * 1e6:.0f} us, max {h['lateness_max_s'] * 1e3:.2f} ms")
    for p in s.get("pushes", []):
        print(f"push by {p['user']}: {'accepted' if p['accepted'] else 'refused'} "
              f"{p.get('gain_set_sha256', '')[:12]} {p.get('reason', '')}")
    print(f"run log: {s['log_csv']} and {s['log_json']}")


def _printed(printer, arg):
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        printer(arg)
    return out.getvalue().splitlines()


@pytest.fixture(scope="module")
def gains_path(tmp_path_factory, study, feedforward):
    return write_gain_set(tmp_path_factory.mktemp("gains") / "gains.json", study, feedforward)


@pytest.mark.parametrize("fault", [None, "offset@1=200"], ids=["completed", "tripped"])
def test_the_record_prints_what_the_summary_printed_on_the_same_run(gains_path, tmp_path, fault):
    run = run_rig(gains_path, realtime=False, log_dir=tmp_path, faults=None if fault is None else [parse_fault(fault)])
    assert run.record.status == run.summary["status"] == ("completed" if fault is None else "tripped")
    lines = _printed(_print_rig_run, run)
    assert lines == _printed(_summary_printer, run.summary)
    # the text comes from the record: without the summary's dict it is the same
    assert _printed(_print_rig_run, replace(run, summary={})) == lines
    assert ("step: rise" in lines[1]) == (fault is None) and any(("stopped by interlock" in x) for x in lines) == bool(
        fault), lines
    # a served rig's pushes: the record's run with the pushes it took, beside the summary that printed them
    from piezopreload.rig.opcua import PushTaken

    pushes = (PushTaken("ops", gain_set_sha256="ab" * 32, accepted=True),
              PushTaken("guest", accepted=False, reason="not a validated gain set"))
    served = replace(run, summary={**run.summary, "pushes": [p.to_dict() for p in pushes]}, pushes=pushes)
    assert _printed(_print_rig_run, served) == _printed(_summary_printer, served.summary)
    assert _printed(_print_rig_run, served)[-3:-1] == [f"push by ops: accepted {'ab' * 6} ",
                                                       "push by guest: refused  not a validated gain set"]


def test_rig_run_json_keeps_its_keys_and_agrees_with_the_record(gains_path, tmp_path, capsys):
    assert main(["rig", "run", str(gains_path), "--fast", "--log-dir", str(tmp_path), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert set(doc) == JSON_KEYS, set(doc) ^ JSON_KEYS
    from piezopreload.artifacts.rigrun import RigRunRecord

    record = RigRunRecord.load(doc["log_json"])
    assert (doc["status"], doc["cycles"], doc["rate_Hz"], doc["backend"]) == (
        record.status, record.summary.cycles, record.rate_Hz, record.backend)
    assert doc["metrics"] == record.summary.metrics.to_dict() and doc["interlocks"] == record.safety.to_dict()
