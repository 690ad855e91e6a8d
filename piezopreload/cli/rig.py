"""``rig run``, ``rig serve``, ``rig push`` and ``rig check``: the rig executor from the command line."""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, TypedDict, overload

from piezopreload.cli._common import (
    PASSWORD_ENV,
    Parser,
    accept_flag,
    fmt,
    json_flag,
    say,
)
from piezopreload.core.errors import InputError, InternalError

if TYPE_CHECKING:
    from piezopreload.artifacts.hostcheck import HostCheck
    from piezopreload.rig.backends import Fault
    from piezopreload.rig.plc_push import PlcPush
    from piezopreload.rig.session import RigRun, ServedPush


# --------------------------------------------------------------------------------------
# rig run / serve / push
# --------------------------------------------------------------------------------------
def _key_values(pairs: list[str] | None, option: str) -> dict[str, str]:
    out = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise InputError(f"{option} '{pair}': expected KEY=VALUE")
        out[key.strip()] = value.strip()
    return out


class RigOptions(TypedDict):
    """The options ``rig run`` and ``rig serve`` share, as :func:`piezopreload.rig.session.run` and
    :func:`~piezopreload.rig.session.serve` take them (the reference is each command's own)."""

    backend: str
    backend_options: dict[str, str]
    log_dir: str
    seed: int
    faults: list[Fault]
    loop: str
    safety: dict[str, float | None]
    host_check_s: float
    accept_host: bool


def _rig_common(args: argparse.Namespace) -> RigOptions:
    from piezopreload.rig.backends import parse_fault

    return RigOptions(backend=args.backend, backend_options=_key_values(args.backend_option, "--backend-option"),
                      log_dir=args.log_dir, seed=args.seed, faults=[parse_fault(f) for f in args.inject or []],
                      loop=args.loop, safety={"force_max_N": args.force_max_N,
                                              "force_low_margin_N": args.force_low_margin_N,
                                              "ramp_s": args.ramp_s, "stall_limit_s": args.stall_limit_s},
                      host_check_s=args.host_check_s, accept_host=args.accept_host)


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a number") from None
    if not (value > 0 and value != float("inf")):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


def _quiet_asyncua() -> None:
    import logging

    logging.getLogger("asyncua").setLevel(logging.CRITICAL)


@overload
def _password(args: argparse.Namespace, required: Literal[True]) -> str: ...


@overload
def _password(args: argparse.Namespace, required: bool) -> str | None: ...


def _password(args: argparse.Namespace, required: bool) -> str | None:
    password = os.environ.get(PASSWORD_ENV)
    if password is None and required:
        if sys.stdin.isatty():
            import getpass

            return getpass.getpass(f"password for {args.user}: ")
        raise InputError(f"--user {args.user}: set the password in the environment variable {PASSWORD_ENV} "
                         "(it is never taken on the command line, where other users could read it)")
    return password


def _rig_arguments(p: argparse.ArgumentParser) -> None:
    from piezopreload.artifacts.gainset import REFERENCES
    from piezopreload.rig.backends import FAULT_KINDS

    p.add_argument("gains", metavar="gains.json",
                   help="a validated gain set (candidates and tampered files are refused)")
    p.add_argument("--backend", default="sim", help="sim (the simulated rig, default) or an installed hardware plug-in")
    p.add_argument("--backend-option", action="append", metavar="KEY=VALUE", help="passed to the backend (repeatable)")
    p.add_argument("--reference", metavar="|".join(REFERENCES) + "|FILE.csv",
                   help="the step or trajectory of the gain set's study, as the gain set stores them, or a CSV of "
                        "time_s,force_N from 0 s, at most an hour long (default step; with --learned the signal's own)")
    p.add_argument("--log-dir", default="runs", metavar="DIR", help="where the run log goes (default runs/)")
    p.add_argument("--seed", type=int, default=0, help="noise seed of the simulated rig (default 0)")
    p.add_argument("--force-max-N", type=_positive_float, metavar="N",
                   help="interlock: highest force (default: the gain set's study's [rig_run] force_max_N)")
    p.add_argument("--force-low-margin-N", type=_positive_float, metavar="N",
                   help="interlock: margin below the bolt preload (default: the gain set's study's)")
    p.add_argument("--ramp-s", type=_positive_float, metavar="S",
                   help="time to ramp the voltage down on a stop (default: the gain set's study's)")
    p.add_argument("--stall-limit-s", type=_positive_float, metavar="S",
                   help="interlock: the longest hold of the output without an update; at most what the plant "
                        "tolerates (default: that, derived from the gain set's plant; see docs/rig.md)")
    p.add_argument("--host-check-s", type=_positive_float, default=2.0, metavar="S",
                   help="in real time, check the host this long before arming (default 2 s; see 'rig check')")
    p.add_argument("--accept-host", action="store_true",
                   help="run on a host that fails the check (recorded in the run's sidecar)")
    accept_flag(p, "run (recorded in the run's sidecar)")
    p.add_argument("--loop", choices=("auto", "native", "python"), default="auto",
                   help="the fixed-rate loop: native (a C thread; the simulated rig or a C-ABI library backend), "
                        "python (the interpreter; any backend), auto (native where it can run, default)")
    p.add_argument("--inject", action="append", metavar="KIND@T_S[=VALUE][/DURATION_S]",
                   help="fire drill: inject a fault into the backend at T_S (repeatable); KIND: "
                        + "; ".join(f"{k}: {v}" for k, v in FAULT_KINDS.items()))
    json_flag(p)


def register_rig(sub: Any) -> None:
    """run, serve and push gains on the rig executor"""
    from piezopreload.rig import DEFAULT_ENDPOINT as DEFAULT_RIG_ENDPOINT
    from piezopreload.rig import SECURITY_MODES, SECURITY_POLICIES

    rig = sub.add_parser("rig",
                         description="The rig executor: a validated gain set at a fixed rate against a backend, "
                                     "behind interlocks, with a run log; served over OPC UA; gains pushed to it.")
    rig_sub = rig.add_subparsers(dest="rig_command", metavar="run|serve|push|check", parser_class=Parser, required=True)
    p = rig_sub.add_parser(
        "run", help="run a validated gain set on a backend",
        description=(
            "Run the controller step (inverse-P-I feedforward + PID) of a validated gain set at its fixed rate with "
            "absolute deadlines, against the simulated rig (default) or a hardware backend, behind the interlocks "
            "(voltage clamp and slew limit; force, sensor NaN/stale/range, the output held longer than the plant "
            "tolerates, SIGINT/SIGTERM, exceptions: each ramps the voltage down, disarms and exits 3). The interlocks' "
            "limits come from the gain set's study unless given here. In real time the host is checked first "
            "('rig check'). Writes the run log (CSV + JSON sidecar) and prints the step metrics (or the trip) and "
            "the loop's timing."),
        epilog="exit codes: 0 completed, 1 internal failure, 2 bad input, 3 stopped by an interlock or a signal")
    _rig_arguments(p)
    p.add_argument("--rate", type=float, metavar="HZ", help="the loop's rate; must be the gain set's (default: it)")
    p.add_argument("--learned", metavar="FILE", help="play back a learned signal ('piezopreload learn --out'): its "
                   "plan as the setpoint, its ff_extra_V added to the feedforward; its reference unless --reference")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--realtime", action="store_true", help="pace the loop in real time (default)")
    mode.add_argument("--fast", action="store_true", help="run the cycles back to back (simulated backend)")
    p.set_defaults(run=_cmd_rig_run, show=_print_rig_run)

    p = rig_sub.add_parser(
        "serve", help="run in real time and serve the rig over OPC UA",
        description=(
            "Run a validated gain set in real time like 'rig run' (the reference's last level held after its end) and "
            "serve it over OPC UA: CtrlP, CtrlTi, CtrlTd (LADS names), the gain set's and the feedforward's hashes, "
            "setpoint, force, voltage, state, last event, and the method PushGainSetWithNote(GainSetDocument, Note, "
            "AcceptedMisses) (and PushGainSet(GainSetDocument), its first form, for the clients written then), which "
            "takes any validated gain set of this rig's plant whose limits fit the interlocks the rig was armed with. "
            "Anonymous sessions are refused: --user is required. The host is checked first ('rig check'). Ends on "
            "SIGINT/SIGTERM (exit 3) or after --duration (exit 0)."),
        epilog=f"The password of --user is read from ${PASSWORD_ENV}.")
    _rig_arguments(p)
    p.add_argument("--endpoint", default=DEFAULT_RIG_ENDPOINT, help=f"default {DEFAULT_RIG_ENDPOINT} (loopback)")
    p.add_argument("--user", metavar="NAME", help=f"the user allowed to push; password in ${PASSWORD_ENV}")
    p.add_argument("--certificate", metavar="CERT",
                   help="the server's certificate: enables Basic256Sha256 SignAndEncrypt only")
    p.add_argument("--private-key", metavar="KEY", help="the server certificate's private key")
    p.add_argument("--duration", type=float, metavar="S", help="serve this long, then ramp down and exit 0")
    p.set_defaults(run=_cmd_rig_serve, show=_print_rig_run)

    p = rig_sub.add_parser(
        "push", help="push a validated gain set to a serving rig, or to a PLC's own OPC UA server",
        description=("Push a validated gain set to 'rig serve' through the OPC UA method PushGainSetWithNote; the "
                     "served rig checks it again (its plant, its status, its limits against the armed interlocks) and "
                     "switches bumplessly at its next cycle, also to another structure (a gain schedule where there "
                     "was none). With --to and --map, write the numbers its PLC block reads (the gains or the "
                     "schedule's arrays, the output range, the feedforward's table, by the names of the PLC export's "
                     "PP_CONTROLLER) to the nodes the map names on any OPC UA server, read them back and report the "
                     "difference; a node missing, of another type or shape or not writable is refused by name and "
                     "nothing is written. Candidates, tampered files, gain sets of another plant or with stricter "
                     "limits, wrong passwords and refused calls exit 2 with the reason."),
        epilog=f"The password of --user is read from ${PASSWORD_ENV} (or asked for on a terminal).")
    p.add_argument("gains", metavar="gains.json", help="a validated gain set")
    p.add_argument("--endpoint", metavar="URL", help=f"the served rig (default {DEFAULT_RIG_ENDPOINT})")
    p.add_argument("--to", metavar="URL", help="a PLC's own OPC UA server (opc.tcp://HOST:PORT), with --map")
    p.add_argument("--map", metavar="NODES.toml", help="with --to: which node holds which number (docs: a PLC over "
                                                       "OPC UA)")
    p.add_argument("--user", metavar="NAME", help=f"user name; password in ${PASSWORD_ENV}")
    p.add_argument("--certificate", metavar="CERT", help="the client's certificate (a secure channel)")
    p.add_argument("--private-key", metavar="KEY", help="the client certificate's private key")
    p.add_argument("--server-certificate", metavar="CERT", help="the server's certificate, to trust it")
    p.add_argument("--security-policy", default="Basic256Sha256", choices=list(SECURITY_POLICIES),
                   help="with a certificate: the secure channel's policy (default Basic256Sha256; a served rig offers "
                        "that one only)")
    p.add_argument("--security-mode", default="SignAndEncrypt", choices=list(SECURITY_MODES),
                   help="with a certificate: sign, or sign and encrypt (default; a served rig offers that one only)")
    p.add_argument("--note", default="", metavar="TEXT", help="why it is pushed, recorded with the push in the run log")
    accept_flag(p, "pushed (sent with the push and recorded with it)")
    json_flag(p)
    p.set_defaults(run=_cmd_rig_push, show=_print_rig_push)

    p = rig_sub.add_parser(
        "check", help="measure this host's wake-up lateness against the loop's budget",
        description=("A bare thread at the loop's priority and rate measures how late this host wakes it (p50, p99, "
                     "p99.9, max, missed), shows a histogram, compares it with the loop's budget (the period and the "
                     "controller step's compute time) and, with --gains, the gain set's stall limit, and names what "
                     "matters (an RT kernel or not, SCHED_FIFO and memory locking, CPU governor, virtualisation, "
                     "isolated CPUs). The verdict is pass or fail (see docs/rig-check.md)."),
        epilog="exit codes: 0 the check ran (whatever its verdict), 1 internal failure, 2 bad input")
    p.add_argument("--gains", metavar="gains.json", help="a validated gain set: its rate, its step, its stall limit")
    p.add_argument("--seconds", type=_positive_float, default=10.0, metavar="S", help="how long (default 10 s)")
    p.add_argument("--rate", type=_positive_float, metavar="HZ",
                   help="the loop's rate (default the gain set's, or 1000)")
    p.add_argument("--loop", choices=("native", "python"), default="native",
                   help="whose wait to measure: the native loop's C thread (default) or the Python loop's")
    p.add_argument("--out", metavar="DIR", help="write the histogram's figure there (host-check.png)")
    json_flag(p)
    p.set_defaults(run=_cmd_rig_check, show=_print_rig_check)


def _cmd_rig_run(args: argparse.Namespace) -> RigRun:
    from piezopreload.rig import session

    # a learned signal without --reference plays on its own reference
    reference = None if args.learned and args.reference is None else args.reference or "step"
    return session.run(args.gains, rate_Hz=args.rate, realtime=not args.fast, learned=args.learned, say=say,
                       accepted=tuple(args.accept), reference=reference, **_rig_common(args))


def _cmd_rig_serve(args: argparse.Namespace) -> RigRun:
    from piezopreload.rig import session

    _quiet_asyncua()
    if args.user is None:
        raise InputError("rig serve: give --user NAME (password in $" + PASSWORD_ENV
                         + "); anonymous sessions are refused")
    users = {args.user: _password(args, True)}
    if args.certificate is None:
        say("warning: no --certificate: passwords cross the network unencrypted; keep the endpoint on loopback")
    return session.serve(args.gains, endpoint=args.endpoint, users=users, certificate=args.certificate,
                         private_key=args.private_key, duration_s=args.duration, say=say,
                         reference=args.reference or "step", **_rig_common(args))


def _cmd_rig_push(args: argparse.Namespace) -> ServedPush | PlcPush:
    from piezopreload.rig import DEFAULT_ENDPOINT as DEFAULT_RIG_ENDPOINT
    from piezopreload.rig import plc_push, session
    from piezopreload.rig.opcua import Credentials

    _quiet_asyncua()
    if (args.to is None) != (args.map is None):
        raise InputError("rig push: --to URL and --map NODES.toml go together (a PLC's server and where its numbers "
                         "are); without them the gain set goes to a served rig (--endpoint)")
    if args.to is not None and args.endpoint is not None:
        raise InputError("rig push: --endpoint is the served rig's, --to a PLC's: give one")
    if args.to is not None and args.note:
        raise InputError("rig push: --note is recorded by a served rig (--endpoint); a push to a PLC (--to) keeps no "
                         "note: leave it out")
    password = _password(args, args.user is not None) if args.user else None
    try:
        who = Credentials(args.user, password, args.certificate, args.private_key, args.server_certificate,
                          args.security_policy, args.security_mode)
    except ValueError as exc:
        raise InputError(f"rig push: {exc}") from None
    if args.to is None:
        return session.push(args.gains, endpoint=args.endpoint or DEFAULT_RIG_ENDPOINT, who=who, note=args.note,
                            accepted=tuple(args.accept))
    return plc_push.push(args.gains, to=args.to, map_path=args.map, who=who, accepted=tuple(args.accept))


def _print_rig_run(run: RigRun) -> None:
    """The run as its sidecar records it (``run.record``): how it ended, its figures, its limits and its timing."""
    r = run.record
    o = r.summary
    if o is None:  # a run ends with its outcome recorded; the summary is what --json prints of it
        raise InternalError(f"{run.log_json}: the run ended without its outcome in the sidecar")
    t = o.timing
    print(f"{r.status}: {o.cycles} cycles at {r.rate_Hz:g} Hz on '{r.backend}' "
          f"({'real time' if r.realtime else 'back to back'}), controller step in {o.controller_step}, "
          f"{t.loop or 'python'} loop")
    if o.trip is not None:
        trip = o.trip
        print(f"stopped by interlock '{trip.cause}' at t = {trip.t_s:.3f} s with {trip.voltage_V:.4g} V held: "
              f"{trip.detail}")
    m = o.metrics
    if m is not None and m.settling_s is not None:
        print(f"step: rise {fmt(m.rise_s, ' s')}, peak {fmt(m.peak_s, ' s')}, "
              f"settling {fmt(m.settling_s, ' s')}, overshoot {fmt(m.overshoot_N, ' N')}; "
              f"tracking RMS {m.tracking_rms_N:.3g} N")
    elif m is not None and m.tracking_rms_N is not None:
        print(f"tracking RMS {m.tracking_rms_N:.3g} N, largest error {m.tracking_max_N:.3g} N")
    lim, src = r.safety, r.safety_sources
    if src is None:  # a run's sidecar names every limit's source (the session writes them as it arms)
        raise InternalError(f"{run.log_json}: the run's sidecar does not say where its limits came from")
    print(f"interlocks: force {lim.force_low_N:g}..{lim.force_max_N:g} N "
          f"(force_max_N from {src.force_max_N}); stall limit {lim.stall_limit_s * 1e3:g} ms "
          f"(from {src.stall_limit_s})")
    print(f"timing: {t.missed_deadlines} missed deadlines, {t.stalls} stalls (longest hold "
          f"{t.held_max_s * 1e3:.2f} ms), lateness p99 {t.lateness_p99_s * 1e6:.0f} us, max "
          f"{t.lateness_max_s * 1e3:.2f} ms, {t.lost_samples} samples lost"
          + (f"; {t.sched_fifo}; {t.memory_locked}" if t.sched_fifo else ""))
    if r.host_check is not None:
        h = r.host_check
        print(f"host check: {h.verdict}{' (run anyway: --accept-host)' if h.verdict == 'fail' else ''}; "
              f"lateness p99 {h.lateness_p99_s * 1e6:.0f} us, max {h.lateness_max_s * 1e3:.2f} ms")
    for p in run.pushes:
        print(f"push by {p.user}: {'accepted' if p.accepted else 'refused'} "
              f"{(p.gain_set_sha256 or '')[:12]} {p.reason or ''}")
    print(f"run log: {run.log_csv} and {run.log_json}")


@dataclass(frozen=True)
class HostChecked:
    """``rig check``'s result: the check and where its figure was written (None: nowhere); ``--json`` prints the
    check's ``to_dict()`` with its histogram as text and the figure beside it."""

    check: HostCheck
    figure: str | None

    def to_dict(self) -> dict[str, Any]:
        return {**self.check.to_dict(), "histogram_text": self.check.histogram_text(), "figure": self.figure}


def _cmd_rig_check(args: argparse.Namespace) -> HostChecked:
    from pathlib import Path

    from piezopreload.rig import session

    result = session.check(args.gains, seconds=args.seconds, rate_Hz=args.rate, loop=args.loop, progress=say)
    figure = None
    if args.out:
        folder = Path(args.out)
        folder.mkdir(parents=True, exist_ok=True)
        figure = str(folder / "host-check.png")
        result.plot().savefig(figure, dpi=120)
    return HostChecked(result, figure)


def _print_rig_check(checked: HostChecked) -> None:
    s, f = checked.check, checked.check.facts
    print(f"{s.samples} wake-ups at {s.rate_Hz:g} Hz: lateness p50 {s.lateness_p50_s * 1e6:.0f} us, p99 "
          f"{s.lateness_p99_s * 1e6:.0f} us, p99.9 {s.lateness_p999_s * 1e6:.0f} us, max "
          f"{s.lateness_max_s * 1e3:.2f} ms; {s.missed} later than the budget; p99 of the wake-ups that "
          f"waited {s.waited_p99_s * 1e6:.0f} us")
    print(f"budget: the period {s.period_s * 1e6:.0f} us less the step's p99 {s.step_p99_s * 1e6:.2f} us "
          f"({s.step_what})" + (f"; stall limit {s.stall_limit_s * 1e3:g} ms" if s.stall_limit_s else
                                "; no stall limit (give --gains)"))
    print("lateness histogram:")
    print(s.histogram_text())
    print(f"host: {f.kernel} ({'RT kernel' if f.rt_kernel else 'not an RT kernel'}, preemption "
          f"{f.preemption}), {f.cpus} CPUs; {f.sched_fifo}; {f.memory_locked}; "
          f"governor: {f.cpu_governor}; {f.virtualisation}; isolated CPUs: {f.isolated_cpus}")
    for line in s.findings:
        print(f"  - {line}")
    for c in s.criteria:
        print(f"{'pass' if c.passed else 'FAIL'} {c.name}: {c.text}")
    print(f"verdict: {s.verdict}")
    if checked.figure:
        print(f"figure: {checked.figure}")


def _print_rig_push(s: ServedPush | PlcPush) -> None:
    from piezopreload.rig.plc_push import PlcPush

    if isinstance(s, PlcPush):
        for r in s.nodes:
            what = "as written" if r.difference is None or r.difference == 0.0 else \
                f"read back {r.relative_difference:.2g} off (its {r.type} rounding)"
            print(f"{r.name} -> {r.node}: {what}")
        print(f"{s.to}: wrote {len(s.nodes)} nodes from {s.gain_set} ({(s.gain_set_sha256 or '')[:12]}); "
              f"largest difference read back {s.max_relative_difference:.2g} (relative)")
        return
    p = s.reply.server_parameters
    print(f"{s.endpoint}: {s.reply.message}")
    print(f"the server now runs {s.reply.server_gain_set_sha256[:12]}: CtrlP {p['CtrlP']:.6g} V/N, "
          f"CtrlTi {p['CtrlTi']:.6g} s, CtrlTd {p['CtrlTd']:.6g} s")


