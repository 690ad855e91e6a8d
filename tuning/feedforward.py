"""The feedforward of a study: its P-I model identified from a loop measurement, and checked in open loop.

The paper identified a classical P-I model (40 operators, eq. 16's thresholds) from a 0-100 V
loop measurement of its rig and fed the setpoint through the model's inverse, eqs. (19)-(20)
(``docs/models.md``). :func:`identify` does that from the loop simulated on the rig's truth
model, or from a measured ``time_s,voltage_V,force_N`` record, and then drives the rig through
the inverse in open loop over a force triangle (the paper's Figure 6): what the feedforward
alone delivers. :class:`IdentifiedFeedforward` is the result; its artifact (kind
``hysteresis-model``) is read by :func:`read_hysteresis_model`, the one reader of that kind.
"""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from piezopreload.core.artifacts import ArtifactError, package_version, read_artifact, write_artifact
from piezopreload.core.errors import InputError
from piezopreload.core.tables import Record, write_csv
from piezopreload.models.actuator import Rig, RigParams
from piezopreload.models.closedloop import simulate_open_loop, triangle
from piezopreload.models.hysteresis import ClassicalPI, CreepPI, NotInvertibleError, inverse_at, model_from_dict
from piezopreload.tuning.calibrate import FeedforwardModel, LoopExcitation, fit_feedforward, identify_feedforward

__all__ = ["IdentifiedFeedforward", "CompensationCheck", "identify", "compensation_check", "read_hysteresis_model"]

Array = NDArray[np.float64]


def read_hysteresis_model(path: str | Path) -> tuple[FeedforwardModel, dict[str, Any]]:
    """Read a hysteresis-model artifact: the model and the whole document; errors name the file and field."""
    doc = read_artifact(path, "hysteresis-model")
    try:
        return model_from_dict(doc["model"]), doc
    except ValueError as exc:
        raise ArtifactError(f"{path}: {exc}") from None


@dataclass(frozen=True, eq=False)
class CompensationCheck:
    """The rig driven through the inverse model in open loop: desired force, command and the rig's force."""

    time_s: Array
    desired_N: Array
    command_V: Array
    force_N: Array
    measured_N: Array
    settle_s: float  # the first cycle (the creep's start) is left out of the error

    @property
    def error_N(self) -> Array:
        return (self.force_N - self.desired_N)[self.time_s >= self.settle_s]

    @property
    def rms_N(self) -> float:
        return float(np.sqrt(np.mean(self.error_N ** 2)))

    @property
    def max_N(self) -> float:
        return float(np.max(np.abs(self.error_N)))


def compensation_check(rig: RigParams, model: FeedforwardModel, low_N: float, high_N: float, frequency_Hz: float,
                       seed: int) -> CompensationCheck:
    """Two cycles of a ``low_N -> high_N`` force triangle through the inverse of ``model``, in open loop on ``rig``."""
    plant = Rig(rig)
    _, desired = triangle(high_N - low_N, frequency_Hz, 2, plant.dt_s)
    desired = desired + low_N
    command = inverse_at(model, plant.dt_s)(desired)
    run = simulate_open_loop(plant, command, seed=seed)
    return CompensationCheck(run["time_s"], desired, command, run["force_N"], run["measured_N"], 1.0 / frequency_Hz)


@dataclass(frozen=True, eq=False)
class IdentifiedFeedforward:
    """A feedforward's P-I model with where it came from, its fit and (when identified here) its checks.

    ``source`` says how the loop was measured (``kind`` ``simulated`` with the excitation, or
    ``measured`` with the file and its SHA-256); ``fit`` the model's error in % of the force
    span; ``loop`` the record it was fitted to (time_s, voltage_V, force_N) and ``check`` the
    open-loop compensation check, both None for a model read back from its artifact.
    """

    model: FeedforwardModel
    source: dict[str, Any]
    fit: dict[str, float]
    solver_status: str = ""
    loop: dict[str, Array] | None = None
    check: CompensationCheck | None = None
    model_sha256: str | None = None  # of the artifact it was read from
    identification: dict[str, Any] = field(default_factory=dict)
    #: with creep: the same model refitted without it ({"model": ..., "fit": ...}), to show what creep buys
    without_creep: dict[str, Any] | None = None

    def inverse(self) -> Any:
        """The feedforward itself: desired force -> command voltage, eqs. (19)-(20) (with creep: :class:`InverseStep`)."""
        return self.model.inverse()

    def describe(self) -> dict[str, Any]:
        """Where the feedforward came from and how well it fits, in words and numbers (a simulation's record)."""
        src = self.source
        if src.get("kind") == "simulated":
            ex = src["excitation"]
            where = f"identified from a simulated {ex['v_max_V']:g} V, {ex['frequency_Hz']:g} Hz loop measurement of the rig"
        else:
            where = f"identified from the measured loop {src.get('path')}"
        out = {"source": where, "model": self.model.kind, "operators": self.model.n_operators}
        if self.fit:
            out.update(fit_rms_pct=self.fit["rms_pct"], fit_max_pct=self.fit["max_pct"])
        return out

    def info(self) -> dict[str, Any]:
        """How the feedforward was identified, as a gain set records it."""
        out = {"source": self.source, "fit": self.fit}
        return {**out, "model_sha256": self.model_sha256} if self.model_sha256 else out

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"source": self.source, "operators": self.model.n_operators, "fit": self.fit,
                               "model": self.model.to_dict()}
        if self.check is not None:
            out.update(compensation_rms_N=self.check.rms_N, compensation_max_N=self.check.max_N)
        return out

    def save(self, folder: str | Path, inputs: dict[str, Any] | None = None) -> dict[str, Path]:
        """Write ``model.json`` (a hysteresis-model artifact), ``loop.csv`` and ``compensation.csv`` into ``folder``."""
        if self.loop is None or self.check is None:
            raise InputError("this feedforward was read from its artifact: there is no loop record to write again")
        d = Path(folder)
        paths = {"model": d / "model.json", "loop": d / "loop.csv", "compensation": d / "compensation.csv"}
        loop, c = self.loop, self.check
        write_csv(paths["loop"], {**loop, "model_N": self.model(loop["voltage_V"])},
                  f"piezopreload {package_version()}: the feedforward's loop measurement ({self.source['kind']}) and the P-I model's output")
        write_csv(paths["compensation"], {"time_s": c.time_s, "desired_N": c.desired_N, "command_V": c.command_V,
                                          "force_N": c.force_N, "measured_N": c.measured_N},
                  f"piezopreload {package_version()}: open loop through the inverse P-I model: desired force, command, "
                  "the rig's force")
        data_sha = self.source.get("sha256") or hashlib.sha256(paths["loop"].read_bytes()).hexdigest()
        write_artifact(paths["model"], "hysteresis-model", {
            "inputs": {"data": {**self.source, "sha256": data_sha}, **(inputs or {})},
            "units": {"input": "V", "output": "N", "input_name": "voltage_V", "output_name": "force_N"},
            "model": self.model.to_dict(),
            "identification": {"fit": self.fit, "solver_status": self.solver_status,
                               "compensation_rms_N": c.rms_N, "compensation_max_N": c.max_N,
                               **({} if self.without_creep is None else {"without_creep": {
                                   "model": self.without_creep["model"].to_dict(), "fit": self.without_creep["fit"]}})},
        })
        return paths

    @classmethod
    def load(cls, path: str | Path, *, classical: bool = False) -> IdentifiedFeedforward:
        """A feedforward from a hysteresis-model artifact; refuses a model without an inverse (or, with
        ``classical``, one that is not the classical P-I model that tuning and validation run)."""
        model, doc = read_hysteresis_model(path)
        if classical and not isinstance(model, ClassicalPI):
            raise ArtifactError(f"{path}: field 'model.kind': the feedforward is a classical P-I model, not '{model.kind}'")
        try:
            model.inverse()
        except NotInvertibleError as exc:
            raise InputError(f"{path}: the model cannot serve as a feedforward: {exc}") from None
        ident = doc.get("identification") or {}
        source = (doc.get("inputs") or {}).get("data") or {"kind": "file", "path": str(path)}
        fit = ident.get("fit") or {k: v for k, v in ident.get("test", {}).items() if k in ("rms_pct", "max_pct")}
        plain = ident.get("without_creep")
        try:
            without = None if not isinstance(plain, dict) else {
                "model": model_from_dict(plain.get("model"), "identification.without_creep.model"), "fit": plain.get("fit")}
        except ValueError as exc:
            raise ArtifactError(f"{path}: {exc}") from None
        return cls(model, source, fit, ident.get("solver_status", ""),
                   model_sha256=hashlib.sha256(Path(path).read_bytes()).hexdigest(), identification=ident,
                   without_creep=without)

    def plot(self) -> Any:
        """The loop measurement and the model (left), the rig through the inverse in open loop (right)."""
        from matplotlib.figure import Figure

        fig = Figure(figsize=(8.0, 3.2), layout="constrained")
        a, b = fig.subplots(1, 2)
        if self.loop is not None:
            a.plot(self.loop["voltage_V"], self.loop["force_N"], color="0.55", lw=0.8, label="loop measurement")
            a.plot(self.loop["voltage_V"], self.model(self.loop["voltage_V"]), "--", lw=1.0, label="P-I model")
        else:
            v = np.linspace(0.0, float(self.model.thresholds[-1]) * 1.05 or 100.0, 400)
            a.plot(np.r_[v, v[::-1]], self.model(np.r_[v, v[::-1]]), lw=1.0, label="P-I model")
        a.set(xlabel="voltage (V)", ylabel="force (N)", title="the feedforward's P-I model")
        a.legend(fontsize="small")
        if self.check is not None:
            keep = self.check.time_s >= self.check.settle_s
            b.plot(self.check.desired_N[keep], self.check.force_N[keep], lw=0.9, label="rig through the inverse")
            lim = [float(self.check.desired_N.min()), float(self.check.desired_N.max())]
            b.plot(lim, lim, ":", color="0.35", label="ideal")
            b.legend(fontsize="small")
        b.set(xlabel="desired force (N)", ylabel="force (N)", title="open loop through the inverse")
        return fig


def identify(rig: RigParams, excitation: LoopExcitation, record: Record | None = None, *,
             check_range_N: tuple[float, float] = (25.0, 100.0)) -> IdentifiedFeedforward:
    """The feedforward's model from the loop simulated on ``rig`` (``record`` None) or a measured V -> N record.

    The open-loop check runs two cycles of a force triangle over ``check_range_N`` at the
    excitation's frequency (noise seed: the excitation's + 1).
    """
    if record is None:
        model, info = identify_feedforward(Rig(rig), excitation)
        rec = info["record"]
        loop = {"time_s": rec["time_s"], "voltage_V": rec["command_V"], "force_N": rec["measured_N"]}
        source: dict[str, Any] = {"kind": "simulated", "excitation": asdict(excitation)}
    else:
        if record.output_unit != "N" or record.input_unit != "V":
            raise InputError(f"{record.path}: the feedforward needs a voltage (V) -> force (N) loop; "
                             f"the record has {record.input_name} -> {record.output_name}")
        loop = {"time_s": record.time_s, "voltage_V": record.input, "force_N": record.output}
        t = record.time_s
        dt = float((t[-1] - t[0]) / max(t.size - 1, 1))
        model, info = fit_feedforward(record.input, record.output, excitation.n_operators, kind=excitation.kind,
                                      creep=excitation.creep, sample_period_s=dt)
        if isinstance(model, CreepPI):  # the lags resampled exactly at the loop's period
            model = model.with_sample_period(rig.sample_period_s)
        source = {"kind": "measured", "path": record.path, "sha256": record.sha256}
    check = compensation_check(rig, model, *check_range_N, excitation.frequency_Hz, excitation.seed + 1)
    return IdentifiedFeedforward(model, source, info["fit"], info["status"], loop, check,
                                 without_creep=info.get("without_creep"))
