"""A validated gain set on the rig: run it, serve it over OPC UA, push it; the host check, the limits, the scoring.

This module puts the rig floor's parts together for one session: it reads the gain set (the
one reader, :meth:`~piezopreload.artifacts.gainset.GainSet.load`; candidates and changed files
are refused), builds its controller, the reference (one the gain set stores by name, or a
``time_s,force_N`` CSV), the limits (:func:`~piezopreload.rig.limits.run_limits`: the gain
set's study's interlock settings unless the command line overrides them, the plant's command
range, bolt preload and sensor range, the stall limit the plant tolerates, each with its
source), and the backend; in real time it checks the host first
(:func:`~piezopreload.rig.hostcheck.check_host`) and refuses one that fails unless
``accept_host``; it runs :class:`~piezopreload.rig.executor.Executor` with its run log and,
for a completed run, scores it from the samples the log kept in memory (:func:`run_metrics`)
by the code that scores a simulation (:func:`~piezopreload.models.metrics.run_numbers`). A
tripped run reports its trip and no step figures.
"""

from __future__ import annotations

import asyncio
import functools
import math
import signal
import sys
import threading
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from piezopreload.artifacts.gainset import REFERENCES, GainSet
from piezopreload.artifacts.hostcheck import HostCheck
from piezopreload.artifacts.learned import LearnedSignal
from piezopreload.artifacts.rigrun import RigRunRecord, RunMetrics
from piezopreload.core import native
from piezopreload.core.artifacts import finite_or_none
from piezopreload.core.errors import InputError
from piezopreload.core.progress import ProgressLike
from piezopreload.core.tables import read_table
from piezopreload.models.closedloop import PAPER_BAND_N, ClosedLoopRun, Reference
from piezopreload.models.controller import Controller, ControllerModel
from piezopreload.models.metrics import Signal, run_numbers
from piezopreload.rig import native_loop
from piezopreload.rig.backends import BackendError, Fault, FaultInjector, open_backend
from piezopreload.rig.compiled import step_library
from piezopreload.rig.executor import Executor
from piezopreload.rig.export import ExportError, controller_from_gain_set, require_validated
from piezopreload.rig.hostcheck import check_host
from piezopreload.rig.limits import RunLimits, check_fit, run_limits
from piezopreload.rig.opcua import (
    Credentials,
    PushRefused,
    PushReply,
    PushTaken,
    RigServer,
    feedforward_hash,
    push_gain_set,
)
from piezopreload.rig.outcome import RunResult
from piezopreload.rig.runlog import LearnedFigures, RunLog

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["EXIT_TRIPPED", "HOST_CHECK_S", "MAX_REFERENCE_S", "RigRun", "ServedRig", "load_validated", "reference_for",
           "run_metrics", "run", "serve", "push", "check_pushed", "check", "controller_words"]

#: the exit code of a run that an interlock (or a signal) stopped
EXIT_TRIPPED = 3
#: how long a run in real time checks its host before arming
HOST_CHECK_S = 2.0
#: the longest reference a run plays (an hour: a machining cycle's schedule is seconds to minutes; a longer file is a
#: unit mistake, and its samples at the loop's rate would not fit in memory)
MAX_REFERENCE_S = 3600.0


def load_validated(path: str | Path, use: str = "run on the rig", accepted: tuple[str, ...] = ()) -> GainSet:
    """A gain set whose hash matches and that passed validation (or whose every missed requirement is ``accepted``
    by name); anything else is refused (exit 2)."""
    return require_validated(GainSet.load(path), use, str(path), accepted)


def _identity(gain_set: GainSet) -> dict[str, str]:
    model = None if gain_set.feedforward is None else gain_set.feedforward.to_dict()
    return {"gain_set_sha256": gain_set.content_sha256 or "", "feedforward_sha256": feedforward_hash(model)}


def _controller(shown: str | Path, gain_set: GainSet, accepted: tuple[str, ...] = ()) -> Controller:
    try:
        return controller_from_gain_set(gain_set, accepted)
    except (ExportError, ValueError) as exc:
        raise InputError(f"{shown}: {exc}") from None


def controller_words(controller: Controller) -> str:
    """The controller's structure in words: "PID", with its feedforward, its gain schedule and its second-order
    filter where it has them."""
    model, parts = controller.model, ["PID"]
    if model.filter_order == 2:
        parts.append("the measurement through a second-order filter")
    if model.feedforward is not None:
        kind = getattr(getattr(controller.feedforward, "forward", None), "kind", "P-I")
        parts.append(f"a {kind} feedforward of {model.feedforward.n_operators} operators")
    if model.scheduled:
        parts.append(f"a gain schedule of {model.schedule_size} entries")
    return parts[0] + ("" if len(parts) == 1 else " with " + " and ".join(parts[1:]))


@dataclass(frozen=True, eq=False)
class ServedRig:
    """What a served rig's check of a pushed gain set needs (:func:`check_pushed`, run in the server's process).

    ``plant_sha256`` names the rig's plant; ``limits`` are the interlocks it was armed with and where each came from;
    ``overrides`` the command line's (they hold for any gain set pushed); ``reference`` and ``seed`` the run the
    stall limit of a pushed controller is derived on; ``model`` the running controller's structure and ``compiled``
    whether the rig runs compiled steps (and ``native`` on the native loop): a pushed controller of another
    structure is compiled in the server's process before the rig is asked to switch.
    """

    plant_sha256: str
    preset: str | None
    limits: RunLimits
    overrides: dict[str, float | None]
    reference: Reference
    reference_name: str
    seed: int
    watchdog_s: float | None
    dt_s: float
    model: ControllerModel
    compiled: bool
    native: bool


def _same_plant(gain_set: GainSet, served: ServedRig) -> None:
    digest = gain_set.plant_sha256
    if digest is None:
        raise InputError("the pushed gain set names no plant (field 'plant.rig'): a rig runs gain sets validated on "
                         "its own plant only")
    if digest != served.plant_sha256:
        raise InputError(f"the pushed gain set was tuned and validated on another plant ('{gain_set.preset}', plant "
                         f"sha256 {digest[:12]}) than this rig runs ('{served.preset}', {served.plant_sha256[:12]}): a "
                         "gain set runs only on the plant it was validated on")


def _compile(controller: Controller, served: ServedRig) -> None:
    """A controller of another structure than the running one: its step (and start) built now, here, so the rig's
    switch finds them; a compiler that fails refuses the push."""
    if not served.compiled or controller.model == served.model:
        return
    try:
        step_library(controller.model)
        if served.native:
            native_loop.start_library(controller.model)
    except native.NativeBuildError as exc:
        raise InputError(f"the rig cannot compile the pushed controller's step ({exc})") from None


def check_pushed(text: str, served: ServedRig, accepted: tuple[str, ...] = ()) -> tuple[Controller, dict[str, Any]]:
    """The served rig's check of a pushed document, in the server's process: the artifact's checks, its status
    (:func:`~piezopreload.rig.export.require_validated`), the rig's plant (by its hash), the sample period, the limits
    it would be armed with here (:func:`~piezopreload.rig.limits.run_limits` on the served reference with the command
    line's overrides) fitting the armed ones (:func:`~piezopreload.rig.limits.check_fit`), and a controller of
    another structure compiled. A gain set that is not validated runs only where each requirement it missed is in
    ``accepted`` by name. Returns the controller and what the push records (its identity, its structure, the armed
    limits kept that are stricter than its own, the misses accepted).

    Raises ValueError with the reason (the server sends it back to the client).
    """
    shown = "the pushed gain set"
    try:
        gain_set = require_validated(GainSet.parse(text, shown), "pushed", shown, accepted)
        _same_plant(gain_set, served)
        controller = _controller(shown, gain_set, accepted)
        if not math.isclose(controller.dt_s, served.dt_s, rel_tol=1e-12):
            raise InputError(f"{shown} samples every {controller.dt_s:g} s, this rig's loop every {served.dt_s:g} s")
        limits = run_limits(gain_set, controller, served.reference, served.reference_name, overrides=served.overrides,
                            override_source="the served rig's command line", seed=served.seed,
                            watchdog_s=served.watchdog_s)
        kept = check_fit(served.limits.safety, served.limits.sources, limits)
        _compile(controller, served)
    except InputError as exc:
        raise ValueError(str(exc)) from None
    misses = {"accepted_missed": [r.to_dict() for r in gain_set.missed]} if not gain_set.validated else {}
    return controller, {**_identity(gain_set), "controller": controller_words(controller), "interlocks_kept": kept,
                        **misses}


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
    duration = float(t[-1] + (t[-1] - t[-2]))
    if not duration <= MAX_REFERENCE_S:
        raise InputError(f"{spec}: the reference lasts {duration:.6g} s (its last row held one more interval); a run "
                         f"plays at most {MAX_REFERENCE_S:g} s: is time_s in seconds?")
    return Reference(t, f, duration), str(path)


def run_metrics(columns: dict[str, np.ndarray], reference: Reference, band_N: float) -> RunMetrics:
    """Step and tracking metrics of a run's controlled samples (the run log's columns), on the measured force."""
    keep = columns["mode"] == 0
    n = int(keep.sum())
    if n < 2:
        return RunMetrics(n)
    c = {k: v[keep] for k, v in columns.items()}
    peak = float(np.max(c["voltage_V"]))
    if not (reference.times_s.size > 1 and c["time_s"][-1] > reference.times_s[1]):
        return RunMetrics(n, peak)
    # on a rig the measured force is all there is: it stands for the true force too
    run = ClosedLoopRun(t_s=c["time_s"], reference_N=c["reference_N"], force_N=c["measured_N"],
                        measured_N=c["measured_N"], command_V=c["command_V"], voltage_V=c["voltage_V"],
                        p_V=c["p_V"], i_V=c["i_V"], d_V=c["d_V"], ff_V=c["feedforward_V"], reference=reference, seed=0)
    try:
        numbers = run_numbers(run, band_N, Signal.MEASURED)
    except ValueError:  # no step to read (a schedule: ramps, or a first row that repeats the level)
        te = run.tracking_error(t_from_s=0.0)
        numbers = {"tracking_rms_N": float(te.rms_N), "tracking_max_N": float(te.max_N)}
    keys = ("rise_s", "peak_s", "settling_s", "overshoot_N", "tracking_rms_N", "tracking_max_N")
    return RunMetrics(n, peak, **{k: None if (x := numbers.get(k)) is None else finite_or_none(x) for k in keys})


@dataclass(frozen=True, eq=False)
class RigRun:
    """A rig session's outcome: ``summary`` (what ``--json`` prints), the run's samples as kept in memory, its
    sidecar as the run ended (``record``: what the run printed is read from it), the log's files and, for a served
    rig, the pushes it took or refused."""

    summary: dict[str, Any]
    columns: dict[str, np.ndarray]
    record: RigRunRecord
    log_csv: str | None
    log_json: str | None
    pushes: tuple[PushTaken, ...] = ()

    @property
    def ok(self) -> bool:
        return self.summary["status"] == "completed"

    @property
    def exit_code(self) -> int:
        """0 for a completed run, the tripped run's code otherwise (what the command exits with)."""
        return int(self.summary["exit_code"])

    def to_dict(self) -> dict[str, Any]:
        return dict(self.summary)

    def plot(self) -> Figure:
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
    limits: RunLimits
    record: RigRunRecord
    band_N: float
    learned: LearnedSignal | None = None


def _plan(gains_path: str | Path, gain_set: GainSet, controller: Controller, reference: str | None,
          learned: str | Path | None) -> tuple[Reference, str, LearnedSignal | None]:
    """The reference the run follows (the learned signal's own unless one is named) and the learned signal."""
    if learned is None:
        ref, name = reference_for(reference or "step", gain_set, gains_path)
        return ref, name, None
    signal = LearnedSignal.load(learned)
    ref, name = (signal.reference, f"learned {Path(learned).name}") if reference is None else \
        reference_for(reference, gain_set, gains_path)
    signal.check(gain_set.content_sha256, ref, str(learned))
    if not math.isclose(signal.sample_period_s, controller.dt_s, rel_tol=1e-9):
        raise InputError(f"{learned}: learned at {signal.sample_period_s} s a sample, the gain set runs at "
                         f"{controller.dt_s} s")
    return ref, name, signal


def _open(backend: str, backend_options: dict[str, str] | None, gain_set: GainSet, seed: int, realtime: bool,
          faults: list[Fault] | None) -> Any:
    try:
        rig = open_backend(backend, backend_options, plant=gain_set.plant, seed=seed)
    except BackendError as exc:
        raise InputError(str(exc)) from None
    if not realtime and not getattr(rig, "simulated", False):
        raise InputError(f"--fast: the backend '{backend}' does not declare itself a simulation (simulated = True); "
                         "hardware runs in real time")
    return FaultInjector(rig, faults) if faults else rig


def _limits(gain_set: GainSet, controller: Controller, ref: Reference, ref_name: str, signal: LearnedSignal | None,
            learned: str | Path | None, safety: dict[str, float | None] | None, safety_source: str, seed: int,
            watchdog_s: float | None) -> RunLimits:
    checked = [(ref, ref_name)]
    if signal is not None:  # the plan is what the loop runs: its levels are held to the same range
        checked.append((signal.setpoint, f"setpoint_N of {learned}"))
    runs = ref if signal is None else signal.setpoint
    return run_limits(gain_set, controller, runs, ref_name, overrides=safety, override_source=safety_source,
                      ff_extra_V=None if signal is None else signal.ff_extra_V, seed=seed, watchdog_s=watchdog_s,
                      checked=tuple(checked))


def _setup(gains_path: str | Path, backend: str, backend_options: dict[str, str] | None, reference: str | None,
           rate_Hz: float | None, realtime: bool, faults: list[Fault] | None, safety: dict[str, float | None] | None,
           seed: int, learned: str | Path | None = None, safety_source: str = "the command line",
           accepted: tuple[str, ...] = ()) -> _Setup:
    gain_set = load_validated(gains_path, accepted=accepted)
    controller = _controller(gains_path, gain_set, accepted)
    if rate_Hz is not None and not math.isclose(rate_Hz * controller.dt_s, 1.0, rel_tol=1e-9):
        raise InputError(f"--rate {rate_Hz:g}: the gain set was tuned and validated at {1.0 / controller.dt_s:g} Hz; "
                         "run it at that rate or tune for the other one")
    ref, ref_name, signal = _plan(gains_path, gain_set, controller, reference, learned)
    wd = backend_options.get("watchdog_s") if backend == "sim" and backend_options else None
    try:
        watchdog_s = None if wd is None else float(wd)
    except ValueError:
        raise InputError(f"--backend-option watchdog_s={wd!r}: not a number") from None
    limits = _limits(gain_set, controller, ref, ref_name, signal, learned, safety, safety_source, seed, watchdog_s)
    rig = _open(backend, backend_options, gain_set, seed, realtime, faults)
    identity = _identity(gain_set)
    record = RigRunRecord(
        gain_set=str(gains_path), backend=rig.name, rig_preset=gain_set.preset, reference=ref_name,
        reference_levels_N=tuple(ref.levels_N.tolist()), rate_Hz=1.0 / controller.dt_s, realtime=realtime,
        safety=limits.safety, safety_sources=limits.sources, stall_limit=limits.stall, seed=seed,
        faults_injected=tuple({**f.__dict__, "duration_s": f.duration_s if math.isfinite(f.duration_s) else None}
                              for f in faults or []), gain_set_sha256=identity["gain_set_sha256"],
        feedforward_sha256=identity["feedforward_sha256"],
        accepted_missed=tuple(r.to_dict() for r in gain_set.require_usable(accepted)))
    if signal is not None:
        record = replace(record, learned={"path": str(learned), "sha256": signal.content_sha256,
                                          "iteration": signal.iteration, "method": signal.method,
                                          "preview_s": signal.preview_s, "reference_sha256": signal.reference_sha256})
    band = gain_set.criteria.band_N if gain_set.criteria is not None else PAPER_BAND_N
    return _Setup(gain_set, controller, rig, ref, limits, record, band, signal)


def _check_host(su: _Setup, executor: Executor, seconds: float, accept_host: bool,
                say: Callable[[str], None] | None) -> HostCheck:
    """The host check before arming; a failing host is refused (exit 2) unless ``accept_host``."""
    checked = check_host(rate_Hz=1.0 / su.controller.dt_s, seconds=seconds, controller=su.controller,
                         stall_limit_s=su.limits.safety.stall_limit_s, loop=executor.loop, progress=say)
    if not checked.passed and not accept_host:
        failed = "; ".join(c.text for c in checked.criteria if not c.passed)
        raise InputError(f"this host failed the check before arming ({failed}); see 'piezopreload rig check', or "
                         "give --accept-host to run on it anyway")
    if say is not None:
        say(f"host check: {checked.verdict} (lateness p99 {checked.lateness_p99_s * 1e6:.0f} us, max "
            f"{checked.lateness_max_s * 1e3:.2f} ms){'; run anyway (--accept-host)' if not checked.passed else ''}")
    return checked


def _summary(result: RunResult, log: RunLog, su: _Setup) -> RigRun:
    """What ``--json`` prints: a tripped run's trip and no step figures, a completed run's figures."""
    columns = log.columns()
    metrics = None
    if result.ok:
        metrics = run_metrics(columns, su.reference, su.band_N)
        log.record_metrics(metrics, None if su.learned is None else _learned_metrics(columns, su.learned))
    rec = log.record
    summary: dict[str, Any] = {
        "status": result.status, "exit_code": 0 if result.ok else EXIT_TRIPPED,
        "trip": None if result.trip is None else asdict(result.trip),
        "cycles": result.cycles, "controller_step": result.controller_step, "loop": result.timing.loop,
        "timing": asdict(result.timing), "clamped_cycles": result.clamped_cycles,
        "metrics": None if metrics is None else asdict(metrics),
        "log_csv": result.csv_path, "log_json": result.json_path,
        "gain_set": rec.gain_set, "gain_set_sha256": rec.gain_set_sha256, "feedforward_sha256": rec.feedforward_sha256,
        "backend": rec.backend, "reference": rec.reference, "rate_Hz": rec.rate_Hz, "realtime": rec.realtime,
        "interlocks": rec.safety.to_dict(), "interlock_sources": su.limits.sources.to_dict(),
        "stall_limit": None if rec.stall_limit is None else asdict(rec.stall_limit),
        "host_check": None if rec.host_check is None else rec.host_check.to_dict(), "host_accepted": rec.host_accepted,
        "events": [e["event"] for e in result.events],
    }
    if su.learned is not None:
        summary["learned"] = dict(rec.learned or {})
    return RigRun(summary, columns, rec, result.csv_path, result.json_path)


def _learned_metrics(columns: dict[str, np.ndarray], signal: LearnedSignal) -> LearnedFigures:
    """A learned run's error against the reference it was learned on (the log's reference_N is the plan)."""
    keep = columns["mode"] == 0
    t, y = columns["time_s"][keep], columns["measured_N"][keep]
    scored = t >= (signal.reference.times_s[1] if signal.reference.times_s.size > 1 else 0.0)
    if not scored.any():
        return LearnedFigures()
    e = signal.reference.at(t[scored]) - y[scored]
    plan = np.interp(t[scored], np.arange(signal.setpoint_N.size) * signal.sample_period_s, signal.setpoint_N)
    return LearnedFigures(tracking_rms_measured_N=float(np.sqrt(np.mean(e**2))),
                          plan_rms_measured_N=float(np.sqrt(np.mean((plan - y[scored]) ** 2))))


def run(gains_path: str | Path, *, backend: str = "sim", backend_options: dict[str, str] | None = None,
        reference: str | None = "step", rate_Hz: float | None = None, realtime: bool = True,
        log_dir: str | Path = "runs", faults: list[Fault] | None = None,
        safety: dict[str, float | None] | None = None, seed: int = 0, step: str = "c",
        learned: str | Path | None = None, loop: str = "auto", safety_source: str = "the command line",
        host_check_s: float = HOST_CHECK_S, accept_host: bool = False,
        say: Callable[[str], None] | None = None, accepted: tuple[str, ...] = ()) -> RigRun:
    """Run a validated gain set on a backend (see ``piezopreload rig run``); the log goes to ``log_dir``.

    ``safety`` overrides the gain set's interlock settings (``force_max_N``, ``force_low_margin_N``,
    ``ramp_s``, ``stall_limit_s``; None: not overridden), ``safety_source`` names where the
    overrides come from in the sidecar. ``learned`` (a learned-signal artifact,
    :class:`~piezopreload.artifacts.learned.LearnedSignal`) plays back a learned signal: its
    setpoint (the plan) is the run's reference and its ``ff_extra_V`` is added to the
    feedforward (on either loop). It must have been learned with this gain set and on this
    reference (``reference=None``: its own); the run's log gives the next learning iteration
    (``piezopreload learn --from-run LOG``). ``loop``: ``auto``, ``native`` or ``python``. In
    real time the host is checked for ``host_check_s`` first (:mod:`piezopreload.rig.hostcheck`)
    and refused if it fails, unless ``accept_host``. A gain set that is not validated is refused unless each
    requirement it missed is named in ``accepted`` (the sidecar records them: ``accepted_missed``).
    """
    su = _setup(gains_path, backend, backend_options, reference, rate_Hz, realtime, faults, safety, seed, learned,
                safety_source, accepted)
    try:
        try:
            plan = su.learned.setpoint if su.learned is not None else su.reference
            executor = Executor(su.controller, su.backend, plan, su.limits.safety, realtime=realtime, step=step,
                                ff_extra_V=None if su.learned is None else su.learned.ff_extra_V, loop=loop)
        except ValueError as exc:
            raise InputError(f"--loop {loop}: {exc}") from None
        record = su.record
        if realtime:
            record = replace(record, host_check=_check_host(su, executor, host_check_s, accept_host, say),
                             host_accepted=accept_host)
        executor.log = log = RunLog(log_dir, (su.gain_set.content_sha256 or "")[:12], record)
        return _summary(executor.run(), log, su)
    finally:
        _close(su.backend)


def _close(backend: Any) -> None:
    close = getattr(backend.inner if isinstance(backend, FaultInjector) else backend, "close", None)
    if callable(close):
        close()


#: a served run keeps this long of its samples in memory for its metrics (the log has them all)
SERVE_KEEP_S = 600.0


def _served(su: _Setup, executor: Executor, overrides: dict[str, float | None] | None, reference: str, seed: int,
            watchdog_s: float | None) -> ServedRig:
    """The served rig as :func:`check_pushed` judges a push against it."""
    return ServedRig(su.gain_set.plant_sha256 or "", su.gain_set.preset, su.limits, dict(overrides or {}), su.reference,
                     reference, seed, watchdog_s, su.controller.dt_s, su.controller.model, executor.step.kind == "c",
                     executor.loop == "native")


def serve(gains_path: str | Path, *, endpoint: str, users: dict[str, str], certificate: str | None = None,
          private_key: str | None = None, backend: str = "sim", backend_options: dict[str, str] | None = None,
          reference: str = "step", log_dir: str | Path = "runs", faults: list[Fault] | None = None,
          safety: dict[str, float | None] | None = None, seed: int = 0, duration_s: float | None = None,
          ready: Any = None, stop: Any = None, say: Any = None, loop: str = "auto",
          host_check_s: float = HOST_CHECK_S, accept_host: bool = False) -> RigRun:
    """Run a validated gain set in real time and serve it over OPC UA until SIGINT/SIGTERM or ``duration_s``.

    The reference's last level is held after its end. A push of another validated gain set
    (of a study with the same interlock settings) switches the running controller bumplessly
    (see :mod:`piezopreload.rig.opcua`). The host is checked first, as by :func:`run`. The
    metrics score the first :data:`SERVE_KEEP_S` seconds.
    """
    su = _setup(gains_path, backend, backend_options, reference, None, True, faults, safety, seed)
    try:
        try:
            executor = Executor(su.controller, su.backend, su.reference, su.limits.safety, realtime=True, hold=True,
                                loop=loop)
            check = _check_host(su, executor, host_check_s, accept_host, say)
            record = replace(su.record, endpoint=endpoint, users=tuple(sorted(users)), served=True, host_check=check,
                             host_accepted=accept_host)
            wd = (backend_options or {}).get("watchdog_s") if backend == "sim" else None
            served = _served(su, executor, safety, reference, seed, None if wd is None else float(wd))
            server = RigServer(executor, functools.partial(check_pushed, served=served),
                               identity=_identity(su.gain_set), endpoint=endpoint, users=users, certificate=certificate,
                               private_key=private_key)
        except (ValueError, OSError) as exc:
            raise InputError(f"rig serve: {exc}") from None
        executor.log = log = RunLog(log_dir, (su.gain_set.content_sha256 or "")[:12], record,
                                    keep_rows=int(SERVE_KEEP_S / su.controller.dt_s))
        if say is not None:
            say(f"serving {endpoint} (log {log.csv_path}); stop with Ctrl-C")
        try:
            out = _summary(asyncio.run(_serve(server, executor, duration_s, ready, stop)), log, su)
        except OSError as exc:  # the server could not start (the address in use, a certificate): nothing ran
            log.not_started(str(exc))
            raise InputError(f"rig serve: {exc}") from None
    finally:
        _close(su.backend)
    out.summary["pushes"] = [p.to_dict() for p in server.pushes]
    return replace(out, pushes=tuple(server.pushes))


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


def check(gains_path: str | Path | None = None, *, seconds: float = 10.0, rate_Hz: float | None = None,
          loop: str = "native", progress: ProgressLike | None = None) -> HostCheck:
    """``piezopreload rig check``: this host against a loop's budget (see :mod:`piezopreload.rig.hostcheck`).

    With a gain set: its rate (``rate_Hz`` must agree), its compiled step and the stall limit
    its step reference would run with; without: ``rate_Hz`` (default 1 kHz), a PID step, and no
    stall limit judged.
    """
    if gains_path is None:
        return check_host(rate_Hz=1000.0 if rate_Hz is None else rate_Hz, seconds=seconds, loop=loop,
                          progress=progress)
    su = _setup(gains_path, "sim", None, "step", rate_Hz, True, None, None, 0)
    _close(su.backend)
    return check_host(rate_Hz=1.0 / su.controller.dt_s, seconds=seconds, controller=su.controller,
                      stall_limit_s=su.limits.safety.stall_limit_s, loop=loop, progress=progress)


@dataclass(frozen=True)
class ServedPush:
    """``rig push`` to a served rig: the gain set pushed (its file and content hash), where, and the rig's reply."""

    gain_set: str
    gain_set_sha256: str | None
    endpoint: str
    reply: PushReply

    def to_dict(self) -> dict[str, Any]:
        return {"gain_set": self.gain_set, "gain_set_sha256": self.gain_set_sha256, "endpoint": self.endpoint,
                **self.reply.to_dict()}


def push(gains_path: str | Path, *, endpoint: str, who: Credentials, note: str = "",
         accepted: tuple[str, ...] = ()) -> ServedPush:
    """Push a validated gain set to a serving rig in the session ``who`` opens (``note``: why, recorded with the push;
    a candidate only where each requirement it missed is ``accepted`` by name, sent with it); refused pushes are bad
    input (exit 2) with the server's reason."""
    gain_set = load_validated(gains_path, "pushed", accepted)  # refuse locally first: nothing sent the server refuses
    text = Path(gains_path).read_text(encoding="utf-8")
    try:
        reply = asyncio.run(push_gain_set(text, endpoint, who, expect_sha256=gain_set.content_sha256, note=note,
                                          accepted=accepted))
    except PushRefused as exc:
        raise InputError(f"{endpoint}: {exc}") from None
    return ServedPush(str(gains_path), gain_set.content_sha256, endpoint, reply)
