"""``piezopreload rig run``: a validated gain set on a backend, its run log and metrics.

This layer reads and checks the files (the gain set, a reference CSV), builds the controller,
the backend and the interlocks, runs :class:`~piezopreload.rig.executor.Executor` and reads
the run log back for the step and tracking metrics, computed by the same code that scores a
simulation.
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

from piezopreload.core.artifacts import parse_artifact, read_artifact
from piezopreload.core.errors import InputError
from piezopreload.core.tables import read_table
from piezopreload.models.actuator import RigParams
from piezopreload.models.closedloop import PAPER_BAND_N, ClosedLoopRun, Reference
from piezopreload.models.controller import Controller
from piezopreload.rig.backends import BackendError, Fault, FaultInjector, open_backend
from piezopreload.rig.executor import Executor, RunResult, Safety
from piezopreload.rig.export import ExportError, controller_from_gain_set
from piezopreload.rig.opcua import PushRefused, RigServer, feedforward_hash, push_gain_set
from piezopreload.rig.runlog import COLUMNS, RunLog

__all__ = ["load_validated_gain_set", "gain_set_controller", "rig_reference", "safety_for", "run_rig", "read_run_log",
           "EXIT_TRIPPED", "REFERENCE_PRESETS"]

#: exit code of a run that an interlock (or a signal) stopped
EXIT_TRIPPED = 3
REFERENCE_PRESETS = ("step", "trajectory")


def _require_validated(doc: dict[str, Any], shown: str) -> dict[str, Any]:
    if doc.get("status") != "validated":
        raise InputError(f"{shown}: the gain set is a '{doc.get('status')}', not 'validated': the rig runs validated "
                         "gains only; run 'piezopreload validate' until it passes")
    return doc


def load_validated_gain_set(path: str | Path) -> dict[str, Any]:
    """A gain set whose hash matches and that passed validation; anything else is refused (exit 2)."""
    return _require_validated(read_artifact(path, "gain-set"), str(path))


def gain_set_identity(doc: dict[str, Any]) -> dict[str, str]:
    return {"gain_set_sha256": doc["content_sha256"],
            "feedforward_sha256": feedforward_hash((doc.get("feedforward") or {}).get("model"))}


def check_pushed_gain_set(text: str) -> tuple[Controller, dict[str, str]]:
    """The executor's check of a pushed document: the artifact's checks, validated, a controller it can build.

    Raises ValueError with the reason (the server sends it back to the client).
    """
    try:
        doc = _require_validated(parse_artifact(text, "gain-set", "the pushed gain set"), "the pushed gain set")
        return gain_set_controller("the pushed gain set", doc), gain_set_identity(doc)
    except InputError as exc:
        raise ValueError(str(exc)) from None


def gain_set_controller(path: str | Path, doc: dict[str, Any]) -> Controller:
    try:
        return controller_from_gain_set(doc)
    except (ExportError, ValueError) as exc:
        raise InputError(f"{path}: {exc}") from None


def gain_set_plant(path: str | Path, doc: dict[str, Any]) -> RigParams | None:
    rig = doc.get("plant", {}).get("rig") if isinstance(doc.get("plant"), dict) else None
    if rig is None:
        return None
    try:
        return RigParams.from_dict(rig)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{path}: field 'plant.rig' is not a rig: {exc}") from None


def rig_reference(spec: str, doc: dict[str, Any], gains_path: str | Path) -> tuple[Reference, str]:
    """The paper's step or trajectory as the gain set stores them, or a CSV of ``time_s,force_N``.

    A CSV's rows are held until the next row (zero-order hold); the last row's level is held
    for one more interval of the file, and the first row must be at ``time_s`` 0.
    """
    if spec in REFERENCE_PRESETS:
        try:
            r = doc["references"][spec]
            return Reference(np.asarray(r["times_s"], float), np.asarray(r["levels_N"], float),
                             float(r["duration_s"])), spec
        except (KeyError, TypeError, ValueError):
            raise InputError(f"{gains_path}: field 'references.{spec}' is missing or invalid; give --reference "
                             "FILE.csv or write the gain set again with 'piezopreload tune'") from None
    path = Path(spec)
    if path.suffix.lower() != ".csv":
        raise InputError(f"--reference: '{spec}' is neither {' nor '.join(REFERENCE_PRESETS)} nor a .csv file")
    table = read_table(path, ("time_s", "force_N"), increasing="time_s")
    t, f = table["time_s"], table["force_N"]
    if t[0] != 0.0:
        raise InputError(f"{spec}: the first row's time_s is {t[0]!r}; the reference must start at 0")
    return Reference(t, f, float(t[-1] + (t[-1] - t[-2]))), str(path)


def safety_for(doc: dict[str, Any], plant: RigParams | None, controller: Controller,
               overrides: dict[str, float | None] | None = None) -> Safety:
    """Interlocks for this gain set and plant: the command range within the gains' and the stacks'."""
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


def read_run_log(csv_path: str | Path) -> dict[str, np.ndarray]:
    """A run log's CSV as named columns (whatever was flushed, also after a kill)."""
    with open(csv_path, encoding="utf-8") as fh:
        header = fh.readline().strip().split(",")
        if tuple(header) != COLUMNS:
            raise InputError(f"{csv_path}:1: not a run log; expected the header {','.join(COLUMNS)}")
        rows = [line for line in fh if line.endswith("\n")]  # a line cut by a kill is left out
    data = np.loadtxt(rows, delimiter=",", ndmin=2) if rows else np.empty((0, len(COLUMNS)))
    return {name: data[:, j] for j, name in enumerate(COLUMNS)}


def run_metrics(log: dict[str, np.ndarray], reference: Reference, band_N: float) -> dict[str, Any]:
    """Step and tracking metrics of the controlled samples, by the code that scores a simulation."""
    keep = log["mode"] == 0
    n = int(keep.sum())
    if n < 2:
        return {"samples": n}
    cols = {k: log[k][keep] for k in ("time_s", "reference_N", "measured_N", "command_V", "voltage_V",
                                       "p_V", "i_V", "d_V", "feedforward_V")}
    run = ClosedLoopRun(t_s=cols["time_s"], reference_N=cols["reference_N"], force_N=cols["measured_N"],
                        measured_N=cols["measured_N"], command_V=cols["command_V"], voltage_V=cols["voltage_V"],
                        p_V=cols["p_V"], i_V=cols["i_V"], d_V=cols["d_V"], ff_V=cols["feedforward_V"],
                        reference=reference, seed=0)
    out: dict[str, Any] = {"samples": n, "peak_voltage_V": float(np.max(cols["voltage_V"]))}
    if reference.times_s.size > 1 and cols["time_s"][-1] > reference.times_s[1]:
        m = run.step_metrics(band_N, signal="measured_N")
        out.update({k: (float(v) if math.isfinite(v) else None) for k, v in
                    (("rise_s", m.rise_s), ("peak_s", m.peak_s), ("settling_s", m.settling_s),
                     ("overshoot_N", m.overshoot))})
        te = run.tracking_error()
        out.update(tracking_rms_N=te["rms"], tracking_max_N=te["max"])
    return out


@dataclass
class _Setup:
    doc: dict[str, Any]
    controller: Controller
    backend: Any
    reference: Reference
    safety: Safety
    info: dict[str, Any]
    band_N: float


def _setup(gains_path: str | Path, backend: str, backend_options: dict[str, str] | None, reference: str,
           rate_Hz: float | None, realtime: bool, faults: list[Fault] | None, safety: dict[str, float | None] | None,
           seed: int) -> _Setup:
    doc = load_validated_gain_set(gains_path)
    controller = gain_set_controller(gains_path, doc)
    if rate_Hz is not None and not math.isclose(rate_Hz * controller.dt_s, 1.0, rel_tol=1e-9):
        raise InputError(f"--rate {rate_Hz:g}: the gain set was tuned and validated at {1.0 / controller.dt_s:g} Hz; "
                         "run it at that rate or tune for the other one")
    plant = gain_set_plant(gains_path, doc)
    ref, ref_name = rig_reference(reference, doc, gains_path)
    interlocks = safety_for(doc, plant if backend == "sim" else None, controller, safety)
    try:
        rig = open_backend(backend, backend_options, plant=plant, seed=seed)
    except BackendError as exc:
        raise InputError(str(exc)) from None
    if not realtime and not getattr(rig, "simulated", False):
        raise InputError(f"--fast: the backend '{backend}' does not declare itself a simulation (simulated = True); "
                         "hardware runs in real time")
    if faults:
        rig = FaultInjector(rig, faults)
    info = {
        "gain_set": str(gains_path), **gain_set_identity(doc), "backend": rig.name,
        "rig_preset": (doc.get("plant") or {}).get("preset"), "reference": ref_name,
        "reference_levels_N": ref.levels_N.tolist(), "rate_Hz": 1.0 / controller.dt_s, "realtime": realtime,
        "safety": interlocks.to_dict(), "seed": seed,
        "faults_injected": [{**f.__dict__, "duration_s": f.duration_s if math.isfinite(f.duration_s) else None}
                            for f in faults or []],
    }
    band = float((doc.get("criteria") or {}).get("band_N", PAPER_BAND_N))
    return _Setup(doc, controller, rig, ref, interlocks, info, band)


def run_rig(
    gains_path: str | Path,
    *,
    backend: str = "sim",
    backend_options: dict[str, str] | None = None,
    reference: str = "step",
    rate_Hz: float | None = None,
    realtime: bool = True,
    log_dir: str | Path = "runs",
    faults: list[Fault] | None = None,
    safety: dict[str, float | None] | None = None,
    seed: int = 0,
    step: str = "c",
) -> dict[str, Any]:
    """Run a validated gain set on a backend and return the summary (see ``piezopreload rig run``)."""
    su = _setup(gains_path, backend, backend_options, reference, rate_Hz, realtime, faults, safety, seed)
    log = RunLog(log_dir, su.doc["content_sha256"][:12], su.info)
    executor = Executor(su.controller, su.backend, su.reference, su.safety, realtime=realtime, log=log, step=step)
    result = executor.run()
    return summary(result, run_metrics(read_run_log(result.csv_path), su.reference, su.band_N), su.info)


def serve_rig(
    gains_path: str | Path,
    *,
    endpoint: str,
    users: dict[str, str],
    certificate: str | None = None,
    private_key: str | None = None,
    backend: str = "sim",
    backend_options: dict[str, str] | None = None,
    reference: str = "step",
    log_dir: str | Path = "runs",
    faults: list[Fault] | None = None,
    safety: dict[str, float | None] | None = None,
    seed: int = 0,
    duration_s: float | None = None,
    ready: Any = None,
    stop: Any = None,
    say: Any = None,
) -> dict[str, Any]:
    """Run a validated gain set in real time and serve it over OPC UA until SIGINT/SIGTERM or ``duration_s``.

    The reference's last level is held after its end. A push of another validated gain set
    switches the running controller bumplessly (see :mod:`piezopreload.rig.opcua`).
    """
    su = _setup(gains_path, backend, backend_options, reference, None, True, faults, safety, seed)
    info = {**su.info, "endpoint": endpoint, "users": sorted(users), "served": True}
    log = RunLog(log_dir, su.doc["content_sha256"][:12], info)
    executor = Executor(su.controller, su.backend, su.reference, su.safety, realtime=True, hold=True, log=log)
    try:
        server = RigServer(executor, check_pushed_gain_set, identity=gain_set_identity(su.doc), endpoint=endpoint,
                           users=users, certificate=certificate, private_key=private_key)
    except (ValueError, OSError) as exc:
        log.close("not started", {"reason": str(exc)})
        raise InputError(f"rig serve: {exc}") from None
    if say is not None:
        say(f"serving {endpoint} (log {log.csv_path}); stop with Ctrl-C")
    result = asyncio.run(_serve(server, executor, duration_s, ready, stop))
    out = summary(result, run_metrics(read_run_log(result.csv_path), su.reference, su.band_N), info)
    out["pushes"] = server.pushes
    return out


async def _serve(server: RigServer, executor: Executor, duration_s: float | None, ready: Any, stop: Any) -> RunResult:
    loop = asyncio.get_running_loop()
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, executor.stop, signal.Signals(sig).name)
    if duration_s is not None:
        loop.call_later(duration_s, lambda: executor.stop(f"the --duration of {duration_s:g} s ended", trip=False))
    switch = sys.getswitchinterval()
    sys.setswitchinterval(1e-4)  # the server's thread hands the interpreter back to the loop's within 0.1 ms
    try:
        return await server.run(ready=ready, stop=stop)
    finally:
        sys.setswitchinterval(switch)


def push_rig(gains_path: str | Path, *, endpoint: str, username: str | None, password: str | None,
             certificate: str | None = None, private_key: str | None = None,
             server_certificate: str | None = None) -> dict[str, Any]:
    """Push a validated gain set to a serving rig; refused pushes are bad input (exit 2) with the server's reason."""
    doc = load_validated_gain_set(gains_path)  # refuse locally first: nothing is sent that the server would refuse
    text = Path(gains_path).read_text(encoding="utf-8")
    try:
        reply = asyncio.run(push_gain_set(text, endpoint, username=username, password=password, certificate=certificate,
                                          private_key=private_key, server_certificate=server_certificate,
                                          expect_sha256=doc["content_sha256"]))
    except PushRefused as exc:
        raise InputError(f"{endpoint}: {exc}") from None
    return {"gain_set": str(gains_path), "gain_set_sha256": doc["content_sha256"], "endpoint": endpoint, **reply}


def summary(result: RunResult, metrics: dict[str, Any], info: dict[str, Any]) -> dict[str, Any]:
    return {
        "status": result.status, "exit_code": 0 if result.ok else EXIT_TRIPPED,
        "trip": None if result.trip is None else result.trip.__dict__,
        "cycles": result.cycles, "controller_step": result.controller_step, "timing": result.timing,
        "clamped_cycles": result.clamped_cycles, "metrics": metrics,
        "log_csv": result.csv_path, "log_json": result.json_path,
        **{k: info[k] for k in ("gain_set", "gain_set_sha256", "feedforward_sha256", "backend", "reference",
                                "rate_Hz", "realtime")},
        "events": [e["event"] for e in result.events],
    }
