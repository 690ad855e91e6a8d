"""A validated gain set on the rig: run it, serve it over OPC UA, push it; the interlocks and the scoring.

This module puts the rig floor's parts together for one session: it reads the gain set (the
one reader, :meth:`~piezopreload.artifacts.gainset.GainSet.load`; candidates and changed files
are refused), builds its controller, the reference (one the gain set stores by name, or a
``time_s,force_N`` CSV), the backend and the interlocks (:func:`interlocks`: the command
range within the gains' and the stacks', the sensor's range and the bolt preload from the
plant), runs :class:`~piezopreload.rig.executor.Executor` with its run log, and scores the
run from the samples the log kept in memory (:func:`run_metrics`) by the code that scores a
simulation (:func:`~piezopreload.models.metrics.run_numbers`).
"""

from __future__ import annotations

import asyncio
import math
import signal
import sys
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from piezopreload.artifacts.gainset import REFERENCES, GainSet
from piezopreload.artifacts.learned import LearnedSignal
from piezopreload.core.errors import InputError
from piezopreload.core.tables import read_table
from piezopreload.models.actuator import Rig, RigParams, reach_N
from piezopreload.models.closedloop import PAPER_BAND_N, ClosedLoopRun, Reference
from piezopreload.models.controller import Controller
from piezopreload.models.metrics import run_numbers
from piezopreload.rig.backends import BackendError, Fault, FaultInjector, open_backend
from piezopreload.rig.executor import Executor, RunResult, Safety
from piezopreload.rig.export import ExportError, controller_from_gain_set
from piezopreload.rig.opcua import PushRefused, RigServer, feedforward_hash, push_gain_set
from piezopreload.rig.runlog import RunLog

__all__ = ["EXIT_TRIPPED", "RigRun", "load_validated", "reference_for", "check_reference", "interlocks", "run_metrics", "run", "serve",
           "push", "check_pushed"]

#: the exit code of a run that an interlock (or a signal) stopped
EXIT_TRIPPED = 3


def _require_validated(gain_set: GainSet, shown: str) -> GainSet:
    if not gain_set.validated:
        raise InputError(f"{shown}: the gain set is a '{gain_set.status}', not 'validated': the rig runs validated "
                         "gains only; run 'piezopreload validate' until it passes")
    return gain_set


def load_validated(path: str | Path) -> GainSet:
    """A gain set whose hash matches and that passed validation; anything else is refused (exit 2)."""
    return _require_validated(GainSet.load(path), str(path))


def _identity(gain_set: GainSet) -> dict[str, str]:
    model = None if gain_set.feedforward is None else gain_set.feedforward.to_dict()
    return {"gain_set_sha256": gain_set.content_sha256 or "", "feedforward_sha256": feedforward_hash(model)}


def _controller(shown: str | Path, gain_set: GainSet) -> Controller:
    try:
        return controller_from_gain_set(gain_set)
    except (ExportError, ValueError) as exc:
        raise InputError(f"{shown}: {exc}") from None


def check_pushed(text: str) -> tuple[Controller, dict[str, str]]:
    """The executor's check of a pushed document: the artifact's checks, validated, a controller it can build.

    Raises ValueError with the reason (the server sends it back to the client).
    """
    shown = "the pushed gain set"
    try:
        gain_set = _require_validated(GainSet.parse(text, shown), shown)
        return _controller(shown, gain_set), _identity(gain_set)
    except InputError as exc:
        raise ValueError(str(exc)) from None


def reference_for(spec: str, gain_set: GainSet, shown: str | Path = "the gain set") -> tuple[Reference, str]:
    """A reference the gain set stores by name (``step``, ``trajectory``) or a CSV of ``time_s,force_N``.

    A CSV's rows are held until the next row (zero-order hold); the last row's level is held
    for one more interval of the file, and the first row must be at ``time_s`` 0.
    """
    if spec in REFERENCES:
        if spec not in gain_set.references:
            raise InputError(f"{shown}: field 'references.{spec}' is missing or invalid; give --reference FILE.csv or "
                             "write the gain set again with 'piezopreload tune'")
        return gain_set.references[spec], spec
    path = Path(spec)
    if path.suffix.lower() != ".csv":
        raise InputError(f"--reference: '{spec}' is neither {' nor '.join(REFERENCES)} nor a .csv file")
    table = read_table(path, ("time_s", "force_N"), increasing="time_s")
    t, f = table["time_s"], table["force_N"]
    if t[0] != 0.0:
        raise InputError(f"{spec}: the first row's time_s is {t[0]!r}; the reference must start at 0")
    return Reference(t, f, float(t[-1] + (t[-1] - t[-2]))), str(path)


def check_reference(reference: Reference, shown: str, limits: Safety, plant: RigParams | None) -> None:
    """Refuse, before arming, a reference outside the interlocks' force range or the plant's reach.

    A level must lie strictly inside the force interlocks (above the bolt preload less the
    margin, below ``force_max_N``: at either limit the run would trip at once), and, with the
    gain set's plant, within what its stacks reach over their voltage range (creep
    settled, :func:`~piezopreload.models.actuator.reach_N`). A CSV's level is named by its line
    (the header is line 1).
    """
    lo, hi = limits.force_low_N, limits.force_max_N
    reach: tuple[float, float] | None = None
    if plant is not None:
        rig = Rig(plant)
        tol = 3.0 * plant.adc_lsb_N
        v_lo, v_hi = plant.stack.v_min_V, plant.stack.v_max_V
        reach = (float(reach_N(rig, v_lo)) - tol, float(reach_N(rig, v_hi)) + tol)
    csv = shown.lower().endswith(".csv")
    for j, level in enumerate(reference.levels_N.tolist()):
        where = f"{shown}:{j + 2}: field 'force_N'" if csv else f"the reference '{shown}', level {j + 1}"
        if not math.isfinite(level) or not lo < level < hi:
            raise InputError(f"{where}: {level:g} N is outside the rig's safe force range ({lo:g} N, {hi:g} N) "
                             "(the bolt preload less the margin, force_max_N); refused before arming")
        if reach is not None and not reach[0] <= level <= reach[1]:
            raise InputError(f"{where}: {level:g} N is beyond what the gain set's plant reaches between "
                             f"its stacks' {v_lo:g} V and {v_hi:g} V ({reach[0]:.4g}..{reach[1]:.4g} N); "
                             "refused before arming")


def interlocks(controller: Controller, plant: RigParams | None, overrides: dict[str, float | None] | None = None) -> Safety:
    """Interlocks for a controller on a plant: the command range within the gains' and the stacks', the force
    floor at the bolt preload, the sensor's range; ``plant`` None (hardware) leaves the plant's limits at
    :class:`Safety`'s defaults. ``overrides`` (not None) win."""
    g = controller.gains
    kw: dict[str, Any] = {"v_min_V": g.u_min, "v_max_V": g.u_max, "safe_V": max(g.u_min, 0.0)}
    if plant is not None:
        kw.update(v_min_V=max(g.u_min, plant.stack.v_min_V), v_max_V=min(g.u_max, plant.stack.v_max_V),
                  bolt_preload_N=float(plant.bolt_preload_N),
                  sensor_min_N=-float(plant.adc_full_scale_N), sensor_max_N=float(plant.adc_full_scale_N) - plant.adc_lsb_N)
    kw.update({k: v for k, v in (overrides or {}).items() if v is not None})
    try:
        return Safety(**kw)
    except (TypeError, ValueError) as exc:
        raise InputError(f"interlocks: {exc}") from None


def run_metrics(columns: dict[str, np.ndarray], reference: Reference, band_N: float) -> dict[str, Any]:
    """Step and tracking metrics of a run's controlled samples (the run log's columns), on the measured force."""
    keep = columns["mode"] == 0
    n = int(keep.sum())
    if n < 2:
        return {"samples": n}
    c = {k: v[keep] for k, v in columns.items()}
    out: dict[str, Any] = {"samples": n, "peak_voltage_V": float(np.max(c["voltage_V"]))}
    if reference.times_s.size > 1 and c["time_s"][-1] > reference.times_s[1]:
        # on a rig the measured force is all there is: it stands for the true force too
        run = ClosedLoopRun(t_s=c["time_s"], reference_N=c["reference_N"], force_N=c["measured_N"],
                            measured_N=c["measured_N"], command_V=c["command_V"], voltage_V=c["voltage_V"],
                            p_V=c["p_V"], i_V=c["i_V"], d_V=c["d_V"], ff_V=c["feedforward_V"], reference=reference, seed=0)
        try:
            numbers = run_numbers(run, band_N, "measured_N")
        except ValueError:  # no step to read (a schedule: ramps, or a first row that repeats the level)
            te = run.tracking_error(t_from_s=0.0)
            numbers = {"rise_s": None, "peak_s": None, "settling_s": None, "overshoot_N": None,
                       "tracking_rms_N": float(te["rms"]), "tracking_max_N": float(te["max"])}
        out.update({k: numbers[k] for k in ("rise_s", "peak_s", "settling_s", "overshoot_N", "tracking_rms_N",
                                             "tracking_max_N")})
    return out


@dataclass(frozen=True, eq=False)
class RigRun:
    """A rig session's outcome: ``summary`` (what ``--json`` prints) and the run's samples as kept in memory."""

    summary: dict[str, Any]
    columns: dict[str, np.ndarray]

    @property
    def ok(self) -> bool:
        return self.summary["status"] == "completed"

    def to_dict(self) -> dict[str, Any]:
        return dict(self.summary)

    def plot(self) -> Any:
        """Reference and measured force (top), amplifier voltage (bottom); grey: the ramp down."""
        from matplotlib.figure import Figure

        c = self.columns
        fig = Figure(figsize=(7.0, 4.5), layout="constrained")
        a, b = fig.subplots(2, 1, sharex=True)
        ramp = c["mode"] != 0
        a.plot(c["time_s"], c["reference_N"], color="0.35", ls="--", label="reference")
        a.plot(c["time_s"], np.where(ramp, np.nan, c["measured_N"]), lw=0.8, label="measured force")
        a.set(ylabel="force (N)")
        a.legend(fontsize="small")
        b.plot(c["time_s"], c["voltage_V"], lw=0.8)
        if ramp.any():
            b.axvspan(float(c["time_s"][ramp][0]), float(c["time_s"][-1]), color="0.9")
        b.set(xlabel="time (s)", ylabel="voltage (V)")
        return fig


@dataclass
class _Setup:
    gain_set: GainSet
    controller: Controller
    backend: Any
    reference: Reference
    safety: Safety
    info: dict[str, Any]
    band_N: float
    learned: LearnedSignal | None = None


def _setup(gains_path: str | Path, backend: str, backend_options: dict[str, str] | None, reference: str | None,
           rate_Hz: float | None, realtime: bool, faults: list[Fault] | None, safety: dict[str, float | None] | None,
           seed: int, learned: str | Path | None = None) -> _Setup:
    gain_set = load_validated(gains_path)
    controller = _controller(gains_path, gain_set)
    if rate_Hz is not None and not math.isclose(rate_Hz * controller.dt_s, 1.0, rel_tol=1e-9):
        raise InputError(f"--rate {rate_Hz:g}: the gain set was tuned and validated at {1.0 / controller.dt_s:g} Hz; "
                         "run it at that rate or tune for the other one")
    signal = None
    if learned is not None:  # the signal's own reference unless one is named; either way its hashes must match
        signal = LearnedSignal.load(learned)
        ref, ref_name = (signal.reference, f"learned {Path(learned).name}") if reference is None else \
            reference_for(reference, gain_set, gains_path)
        signal.check(gain_set.content_sha256, ref, str(learned))
        if not math.isclose(signal.sample_period_s, controller.dt_s, rel_tol=1e-9):
            raise InputError(f"{learned}: learned at {signal.sample_period_s} s a sample, the gain set runs at "
                             f"{controller.dt_s} s")
    else:
        ref, ref_name = reference_for(reference or "step", gain_set, gains_path)
    limits = interlocks(controller, gain_set.plant if backend == "sim" else None, safety)
    check_reference(ref, ref_name, limits, gain_set.plant)
    if signal is not None:  # the plan is what the loop runs: its levels are held to the same range
        check_reference(signal.setpoint, f"setpoint_N of {learned}", limits, gain_set.plant)
    try:
        rig = open_backend(backend, backend_options, plant=gain_set.plant, seed=seed)
    except BackendError as exc:
        raise InputError(str(exc)) from None
    if not realtime and not getattr(rig, "simulated", False):
        raise InputError(f"--fast: the backend '{backend}' does not declare itself a simulation (simulated = True); "
                         "hardware runs in real time")
    if faults:
        rig = FaultInjector(rig, faults)
    info = {
        "gain_set": str(gains_path), **_identity(gain_set), "backend": rig.name, "rig_preset": gain_set.preset,
        "reference": ref_name, "reference_levels_N": ref.levels_N.tolist(), "rate_Hz": 1.0 / controller.dt_s,
        "realtime": realtime, "safety": limits.to_dict(), "seed": seed,
        "faults_injected": [{**f.__dict__, "duration_s": f.duration_s if math.isfinite(f.duration_s) else None}
                            for f in faults or []],
    }
    if signal is not None:
        info["learned"] = {"path": str(learned), "sha256": signal.content_sha256, "iteration": signal.iteration,
                           "method": signal.method, "preview_s": signal.preview_s,
                           "reference_sha256": signal.reference_sha256}
    band = gain_set.criteria.band_N if gain_set.criteria is not None else PAPER_BAND_N
    return _Setup(gain_set, controller, rig, ref, limits, info, band, signal)


def _summary(result: RunResult, log: RunLog, su: _Setup, info: dict[str, Any]) -> RigRun:
    columns = log.columns()
    summary = {
        "status": result.status, "exit_code": 0 if result.ok else EXIT_TRIPPED,
        "trip": None if result.trip is None else result.trip.__dict__,
        "cycles": result.cycles, "controller_step": result.controller_step, "loop": result.timing.get("loop"),
        "timing": result.timing,
        "clamped_cycles": result.clamped_cycles, "metrics": run_metrics(columns, su.reference, su.band_N),
        "log_csv": result.csv_path, "log_json": result.json_path,
        **{k: info[k] for k in ("gain_set", "gain_set_sha256", "feedforward_sha256", "backend", "reference",
                                "rate_Hz", "realtime")},
        "events": [e["event"] for e in result.events],
    }
    if su.learned is not None:
        summary["learned"] = {**info["learned"], **_learned_metrics(columns, su.learned)}
    return RigRun(summary, columns)


def _learned_metrics(columns: dict[str, np.ndarray], signal: LearnedSignal) -> dict[str, Any]:
    """A learned run's error against the reference it was learned on (the log's reference_N is the plan)."""
    keep = columns["mode"] == 0
    t, y = columns["time_s"][keep], columns["measured_N"][keep]
    scored = t >= (signal.reference.times_s[1] if signal.reference.times_s.size > 1 else 0.0)
    if not scored.any():
        return {}
    e = signal.reference.at(t[scored]) - y[scored]
    return {"tracking_rms_measured_N": float(np.sqrt(np.mean(e**2))),
            "plan_rms_measured_N": float(np.sqrt(np.mean((np.interp(t[scored], np.arange(signal.setpoint_N.size) *
                                                                     signal.sample_period_s, signal.setpoint_N)
                                                           - y[scored]) ** 2)))}


def run(gains_path: str | Path, *, backend: str = "sim", backend_options: dict[str, str] | None = None,
        reference: str | None = "step", rate_Hz: float | None = None, realtime: bool = True, log_dir: str | Path = "runs",
        faults: list[Fault] | None = None, safety: dict[str, float | None] | None = None, seed: int = 0,
        step: str = "c", learned: str | Path | None = None, loop: str = "auto") -> RigRun:
    """Run a validated gain set on a backend (see ``piezopreload rig run``); the log goes to ``log_dir``.

    ``learned`` (a learned-signal artifact, :class:`~piezopreload.artifacts.learned.LearnedSignal`)
    plays back a learned signal: its setpoint (the plan) is the run's reference and its
    ``ff_extra_V`` is added to the feedforward (on either loop). It must have been learned with this gain set and on this reference
    (``reference=None``: its own); the run's log gives the next learning iteration
    (``piezopreload learn --from-run LOG``). ``loop``: ``auto``, ``native`` or ``python``.
    """
    su = _setup(gains_path, backend, backend_options, reference, rate_Hz, realtime, faults, safety, seed, learned)
    log = RunLog(log_dir, (su.gain_set.content_sha256 or "")[:12], su.info)
    try:
        if su.learned is not None:
            executor = Executor(su.controller, su.backend, su.learned.setpoint, su.safety, realtime=realtime, log=log,
                                step=step, ff_extra_V=su.learned.ff_extra_V, loop=loop)
        else:
            executor = Executor(su.controller, su.backend, su.reference, su.safety, realtime=realtime, log=log,
                                step=step, loop=loop)
        return _summary(executor.run(), log, su, su.info)
    except ValueError as exc:
        log.close("not started", {"reason": str(exc)})
        raise InputError(f"--loop {loop}: {exc}") from None
    finally:
        _close(su.backend)


def _close(backend: Any) -> None:
    close = getattr(backend.inner if isinstance(backend, FaultInjector) else backend, "close", None)
    if callable(close):
        close()


#: a served run keeps this long of its samples in memory for its metrics (the log has them all)
SERVE_KEEP_S = 600.0


def serve(gains_path: str | Path, *, endpoint: str, users: dict[str, str], certificate: str | None = None,
          private_key: str | None = None, backend: str = "sim", backend_options: dict[str, str] | None = None,
          reference: str = "step", log_dir: str | Path = "runs", faults: list[Fault] | None = None,
          safety: dict[str, float | None] | None = None, seed: int = 0, duration_s: float | None = None,
          ready: Any = None, stop: Any = None, say: Any = None, loop: str = "auto") -> RigRun:
    """Run a validated gain set in real time and serve it over OPC UA until SIGINT/SIGTERM or ``duration_s``.

    The reference's last level is held after its end. A push of another validated gain set
    switches the running controller bumplessly (see :mod:`piezopreload.rig.opcua`). The
    metrics score the first :data:`SERVE_KEEP_S` seconds.
    """
    su = _setup(gains_path, backend, backend_options, reference, None, True, faults, safety, seed)
    info = {**su.info, "endpoint": endpoint, "users": sorted(users), "served": True}
    log = RunLog(log_dir, (su.gain_set.content_sha256 or "")[:12], info,
                 keep_rows=int(SERVE_KEEP_S / su.controller.dt_s))
    try:
        executor = Executor(su.controller, su.backend, su.reference, su.safety, realtime=True, hold=True, log=log,
                            loop=loop)
        server = RigServer(executor, check_pushed, identity=_identity(su.gain_set), endpoint=endpoint,
                           users=users, certificate=certificate, private_key=private_key)
    except (ValueError, OSError) as exc:
        log.close("not started", {"reason": str(exc)})
        _close(su.backend)
        raise InputError(f"rig serve: {exc}") from None
    if say is not None:
        say(f"serving {endpoint} (log {log.csv_path}); stop with Ctrl-C")
    try:
        out = _summary(asyncio.run(_serve(server, executor, duration_s, ready, stop)), log, su, info)
    except OSError as exc:  # the server could not start (the address in use, a certificate): nothing ran
        log.close("not started", {"reason": str(exc)})
        raise InputError(f"rig serve: {exc}") from None
    finally:
        _close(su.backend)
    out.summary["pushes"] = server.pushes
    return out


async def _serve(server: RigServer, executor: Executor, duration_s: float | None, ready: Any, stop: Any) -> RunResult:
    loop = asyncio.get_running_loop()
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, executor.stop, signal.Signals(sig).name)
    if duration_s is not None:
        loop.call_later(duration_s, lambda: executor.stop(f"the --duration of {duration_s:g} s ended", trip=False))
    switch = sys.getswitchinterval()
    sys.setswitchinterval(1e-4)  # the supervisor's thread hands the interpreter back to a Python loop within 0.1 ms
    try:
        return await server.run(ready=ready, stop=stop)
    finally:
        sys.setswitchinterval(switch)


def push(gains_path: str | Path, *, endpoint: str, username: str | None, password: str | None,
         certificate: str | None = None, private_key: str | None = None,
         server_certificate: str | None = None) -> dict[str, Any]:
    """Push a validated gain set to a serving rig; refused pushes are bad input (exit 2) with the server's reason."""
    gain_set = load_validated(gains_path)  # refuse locally first: nothing is sent that the server would refuse
    text = Path(gains_path).read_text(encoding="utf-8")
    try:
        reply = asyncio.run(push_gain_set(text, endpoint, username=username, password=password, certificate=certificate,
                                          private_key=private_key, server_certificate=server_certificate,
                                          expect_sha256=gain_set.content_sha256))
    except PushRefused as exc:
        raise InputError(f"{endpoint}: {exc}") from None
    return {"gain_set": str(gains_path), "gain_set_sha256": gain_set.content_sha256, "endpoint": endpoint, **reply}
