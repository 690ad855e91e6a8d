"""The feedforward of a study: its P-I model identified from a loop measurement, and checked in open loop.

The paper identified a classical P-I model (40 operators, eq. 16's thresholds) from a 0-100 V
loop measurement of its rig and fed the setpoint through the model's inverse, eqs. (19)-(20)
(``docs/models.md``). :func:`identify_feedforward` does that from the loop simulated on the
rig's truth model (:func:`simulate_loop`), or from a measured ``time_s,voltage_V,force_N``
record, through the one identification entry point
(:func:`~piezopreload.tuning.identification.identify`), and then drives the rig through the
inverse in open loop over a force triangle (the paper's Figure 6): what the feedforward alone
delivers. :class:`IdentifiedFeedforward` is the result; its ``model.json`` is the
:class:`~piezopreload.artifacts.hysteresis.IdentifiedModel` artifact.
"""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from piezopreload.artifacts.hysteresis import Compensation, DataSource, FitError, IdentifiedModel, require_coverage
from piezopreload.core._typing import Array
from piezopreload.core.artifacts import ArtifactError, package_version
from piezopreload.core.errors import InputError
from piezopreload.core.records import Checked, checked, entry
from piezopreload.core.tables import MeasuredRecord, write_csv
from piezopreload.models.actuator import Plant, Rig
from piezopreload.models.closedloop import simulate_open_loop, triangle
from piezopreload.models.hysteresis import ClassicalPI, CreepPI, HysteresisModel, NotInvertibleError, inverse_at
from piezopreload.tuning.identification import Window, identify
from piezopreload.tuning.identify import MODELS

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["LoopExcitation", "FeedforwardModel", "IdentifiedFeedforward", "CompensationCheck", "identify_feedforward",
           "simulate_loop", "compensation_check", "loop_covers"]


#: what a study's feedforward may be: a P-I model, with or without creep
FeedforwardModel = HysteresisModel | CreepPI


@checked
class LoopExcitation(Checked):
    """[feedforward]: the loop measurement the feedforward's P-I model is identified from (simulated on the plant's
    truth model, or ``data``, a measured one), the model's kind and whether it compensates creep too.

    ``kind`` is the P-I model (``classical``, ``modified``, ``paper-asymmetric``); ``creep`` adds
    a bank of creep lags (one per decade from 10 ms to the record's length) identified with it.
    """

    v_max_V: float = entry("The triangle's peak voltage.", unit="V", gt=0, default=100.0)
    frequency_Hz: float = entry("The triangle's frequency.", unit="Hz", gt=0, default=0.5)
    cycles: int = entry("Cycles of the triangle.", ge=1, default=3)
    n_operators: int = entry("Play operators of the P-I model.", ge=1, default=40)
    seed: int = entry("Noise seed of the simulated measurement.", ge=0, default=1)
    data: str | None = entry("A measured time_s,voltage_V,force_N loop, relative to the study file (None: the loop "
                             "simulated on the plant).", default=None)
    kind: str = entry("The P-I model.", choices=MODELS, default="classical")
    creep: bool = entry("Identify and compensate creep lags too.", default=False)


def _simulated(excitation: LoopExcitation) -> dict[str, Any]:
    """The simulated measurement's settings as the identified model's source records them (a measured loop's file,
    ``data``, is no setting of a simulation)."""
    return {k: v for k, v in asdict(excitation).items() if k != "data"}


def simulate_loop(rig: Plant, excitation: LoopExcitation) -> MeasuredRecord:
    """The 0..v_max V triangle loop measured on the rig's truth model (sensor noise included): a
    :class:`MeasuredRecord`.

    Its ``sha256`` is that of its samples (float64: time, voltage, force one after the other).
    """
    plant = Rig(rig)
    _, command = triangle(excitation.v_max_V, excitation.frequency_Hz, excitation.cycles, plant.dt_s)
    rec = simulate_open_loop(plant, command, seed=excitation.seed)
    t, v, y = (np.asarray(rec[k], float) for k in ("time_s", "command_V", "measured_N"))
    digest = hashlib.sha256(np.concatenate([t, v, y]).tobytes()).hexdigest()
    return MeasuredRecord("", digest, t, v, y, "voltage_V", "force_N")


def loop_covers(loop: MeasuredRecord, low_N: float, high_N: float, what: str) -> None:
    """Refuse, before identifying anything, a loop whose forces do not cover ``[low_N, high_N]``: the range a
    model identified on the whole loop would have (:func:`~piezopreload.artifacts.hysteresis.require_coverage`)."""
    require_coverage((float(np.min(loop.output)), float(np.max(loop.output))), (low_N, high_N), what,
                     unit=loop.output_unit or "N", source=f"the measured {loop.output_name} of {loop.path}")


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


def compensation_check(rig: Plant, model: FeedforwardModel, low_N: float, high_N: float, frequency_Hz: float,
                       seed: int) -> CompensationCheck:
    """Two cycles of a ``low_N -> high_N`` force triangle through the inverse of ``model``, in open loop on ``rig``."""
    plant = Rig(rig)
    _, desired = triangle(high_N - low_N, frequency_Hz, 2, plant.dt_s)
    desired = desired + low_N
    command = inverse_at(model, plant.dt_s)(desired)
    run = simulate_open_loop(plant, command, seed=seed)
    return CompensationCheck(run["time_s"], desired, command, run["force_N"], run["measured_N"], 1.0 / frequency_Hz)


@dataclass(frozen=True)
class FeedforwardInfo:
    """Where a feedforward came from (in words), its model and play operators, and, where it was identified for the
    run, its fit to the loop (in % of the force span).

    Parameters
    ----------
    source : str
        Where the feedforward came from, in words.
    model : str
        The P-I model's kind.
    operators : int
        Its play operators.
    fit_rms_pct, fit_max_pct : float or None
        Its RMS and largest error on its loop, in % of the force span (None: not identified for the run).
    """

    source: str
    model: str
    operators: int
    fit_rms_pct: float | None = None
    fit_max_pct: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """Where the feedforward came from, as a simulation's record holds it.

        Returns
        -------
        dict
            ``source`` (in words), ``model`` (its kind), ``operators`` and, where a fit was measured, ``fit_rms_pct``
            and ``fit_max_pct`` (% of the force span).
        """
        out: dict[str, Any] = {"source": self.source, "model": self.model, "operators": self.operators}
        if self.fit_rms_pct is not None:
            out |= {"fit_rms_pct": self.fit_rms_pct, "fit_max_pct": self.fit_max_pct}
        return out


@dataclass(frozen=True, eq=False)
class IdentifiedFeedforward:
    """A study's feedforward: its identified P-I model (``record``, as ``model.json`` holds it), and when it was
    identified here rather than read back, the loop it was fitted to and the open-loop compensation check.

    Parameters
    ----------
    record : IdentifiedModel
        The identified model, its errors and where it came from.
    loop : MeasuredRecord or None
        The hysteresis loop it was fitted to (None: read back from ``model.json``).
    check : CompensationCheck or None
        The open-loop check of its inverse on the plant (None: read back).
    """

    record: IdentifiedModel
    loop: MeasuredRecord | None = None
    check: CompensationCheck | None = None

    @property
    def model(self) -> FeedforwardModel:
        """The identified P-I model (voltage in V to force in N)."""
        return self.record.model

    @property
    def source(self) -> DataSource:
        """Where the loop came from (``kind`` ``simulated`` with the excitation, or ``measured`` with the file)."""
        return self.record.data

    @property
    def fit(self) -> FitError:
        """The model's error on the loop, in % of its force span."""
        return self.record.fit

    @property
    def without_creep(self) -> HysteresisModel | None:
        """With creep: the same model refitted without it, to show what creep buys (None without creep)."""
        return None if self.record.without_creep is None else self.record.without_creep.model

    @property
    def model_sha256(self) -> str | None:
        """SHA-256 of the ``model.json`` it was read from or written to."""
        return self.record.file_sha256

    def inverse(self) -> Any:
        """The feedforward itself: desired force -> command voltage, eqs. (19)-(20) (with creep:
        :class:`InverseStep`).

        Returns
        -------
        InverseClassicalPI, InverseAsymmetricPI, InverseModifiedPI or InverseCreepPI
            The model's inverse, a callable from the desired force (N) to the command voltage (V).
        """
        return self.model.inverse()

    def covers(self, low_N: float, high_N: float, what: str = "the references") -> None:
        """Refuse (an :class:`InputError` naming both ranges) forces outside the range the model was identified over.

        Parameters
        ----------
        low_N, high_N : float
            The least and the largest force the feedforward will be asked for, in N.
        what : str
            What asks for them, for the message ("the references").

        Raises
        ------
        InputError
            Where the range lies outside the range the model was identified over.
        """
        self.record.covers(low_N, high_N, what)

    def describe(self) -> FeedforwardInfo:
        """Where the feedforward came from and how well it fits, in words and numbers (a simulation's record).

        Returns
        -------
        FeedforwardInfo
            The source in words, the model's kind and operators, and its fit error (% of the force span).
        """
        src = self.record.data
        if src.kind == "simulated" and src.excitation:
            ex = src.excitation
            where = (f"identified from a simulated {ex['v_max_V']:g} V, "
                     f"{ex['frequency_Hz']:g} Hz loop measurement of the rig")
        else:
            where = f"identified from the measured loop {src.path}"
        return FeedforwardInfo(where, self.model.kind, self.model.n_operators, self.fit.rms_pct, self.fit.max_pct)

    def info(self) -> dict[str, Any]:
        """How the feedforward was identified, as a gain set records it.

        Returns
        -------
        dict
            ``source``, ``fit`` (% of the force span), ``output_range_N`` (N) and, where known, ``model_sha256``.
        """
        out = {"source": self.source.to_dict(), "fit": self.fit.to_dict(),
               "output_range_N": list(self.record.output_range)}
        return {**out, "model_sha256": self.model_sha256} if self.model_sha256 else out

    def to_dict(self) -> dict[str, Any]:
        """What ``identify-feedforward --json`` prints (and a simulation's record holds).

        Returns
        -------
        dict
            ``source``, ``operators``, ``fit`` (% of the force span), ``model`` (its document), ``output_range_N`` (N)
            and, where the open-loop check ran, ``compensation_rms_N`` and ``compensation_max_N`` (N).
        """
        out: dict[str, Any] = {"source": self.source.to_dict(), "operators": self.model.n_operators,
                               "fit": self.fit.to_dict(), "model": self.model.to_dict(),
                               "output_range_N": list(self.record.output_range)}
        if self.check is not None:
            out.update(compensation_rms_N=self.check.rms_N, compensation_max_N=self.check.max_N)
        return out

    def save(self, folder: str | Path, inputs: dict[str, Any] | None = None) -> dict[str, Path]:
        """Write ``model.json`` (the hysteresis-model artifact), ``loop.csv`` and
        ``compensation.csv`` into ``folder``.

        Parameters
        ----------
        folder : str or Path
            The folder the three files are written into.
        inputs : dict or None
            The hashes of the files the model came from, by name, added to those it records.

        Returns
        -------
        dict of str to Path
            ``model``, ``loop`` and ``compensation``: each file's path.

        Raises
        ------
        InputError
            Where the feedforward was read from its artifact (there is no loop record to write).
        """
        if self.loop is None or self.check is None:
            raise InputError("this feedforward was read from its artifact: there is no loop record to write again")
        d = Path(folder)
        paths = {"model": d / "model.json", "loop": d / "loop.csv", "compensation": d / "compensation.csv"}
        loop, c = self.loop, self.check
        write_csv(paths["loop"], {"time_s": loop.time_s, "voltage_V": loop.input, "force_N": loop.output,
                                  "model_N": self.model(loop.input)},
                  f"piezopreload {package_version()}: the feedforward's loop measurement ({self.record.data.kind}) "
                  "and the P-I model's output")
        write_csv(paths["compensation"], {"time_s": c.time_s, "desired_N": c.desired_N, "command_V": c.command_V,
                                          "force_N": c.force_N, "measured_N": c.measured_N},
                  f"piezopreload {package_version()}: open loop through the inverse P-I model: desired force, command, "
                  "the rig's force")
        replace(self.record, inputs={**self.record.inputs, **(inputs or {})}).save(paths["model"])
        return paths

    @classmethod
    def load(cls, path: str | Path, *, classical: bool = False) -> IdentifiedFeedforward:
        """A feedforward from a hysteresis-model artifact; refuses a model without an inverse (or, with
        ``classical``, one that is not the classical P-I model that tuning and validation run).

        Parameters
        ----------
        path : str or Path
            The hysteresis-model artifact.
        classical : bool
            Whether to refuse every model but the classical P-I model.

        Returns
        -------
        IdentifiedFeedforward
            The feedforward, without the loop record and the open-loop check.

        Raises
        ------
        ArtifactError
            Where the file is not a hysteresis-model artifact, or, with ``classical``, not a classical P-I model.
        InputError
            Where the model has no inverse.
        """
        record = IdentifiedModel.load(path)
        if classical and not isinstance(record.model, ClassicalPI):
            raise ArtifactError(f"{path}: field 'model.kind': the feedforward is a classical P-I model, not "
                                f"'{record.model.kind}'")
        try:
            record.model.inverse()
        except NotInvertibleError as exc:
            raise InputError(f"{path}: the model cannot serve as a feedforward: {exc}") from None
        return cls(record)

    def plot(self) -> Figure:
        """The loop measurement and the model (left), the rig through the inverse in open loop (right).

        Returns
        -------
        matplotlib.figure.Figure
            The loop measurement and the model's force (N) against the voltage (V); the rig's force through the inverse
            against the desired force (N), where the check ran.
        """
        from matplotlib.figure import Figure

        fig = Figure(figsize=(8.0, 3.2), layout="constrained")
        a, b = fig.subplots(1, 2)
        if self.loop is not None:
            a.plot(self.loop.input, self.loop.output, color="0.55", lw=0.8, label="loop measurement")
            a.plot(self.loop.input, self.model(self.loop.input), "--", lw=1.0, label="P-I model")
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


def identify_feedforward(rig: Plant, excitation: LoopExcitation, record: MeasuredRecord | None = None, *,
                         check_range_N: tuple[float, float] | None = (25.0, 100.0)) -> IdentifiedFeedforward:
    """The feedforward's model from the loop simulated on ``rig`` (``record`` None) or a measured V -> N record.

    The invertible P-I model of ``excitation.kind`` (the paper's thresholds, eq. (16)) identified
    on the whole loop by :func:`~piezopreload.tuning.identification.identify`; with creep, the
    lags resampled exactly at the rig's period. The open-loop check runs two cycles of a force
    triangle over ``check_range_N`` at the excitation's frequency (noise seed: the excitation's +
    1); None skips it.
    """
    if record is None:
        loop = simulate_loop(rig, excitation)
        source = DataSource("simulated", loop.sha256, None, _simulated(excitation))
    else:
        if record.output_unit != "N" or record.input_unit != "V":
            raise InputError(f"{record.path}: the feedforward needs a voltage (V) -> force (N) loop; "
                             f"the record has {record.input_name} -> {record.output_name}")
        loop, source = record, DataSource("measured", record.sha256, record.path)
    whole = Window(float(loop.time_s[0]), float(loop.time_s[-1]))
    result = identify(loop, model=excitation.kind, operators=excitation.n_operators, thresholds="paper", train=whole,
                      creep=excitation.creep, invertible=True, baselines=False, source=source)
    ident = result.record
    if isinstance(ident.model, CreepPI):  # the lags resampled exactly at the loop's period
        ident = replace(ident, model=ident.model.with_sample_period(rig.sample_period_s))
    check = None
    if check_range_N is not None:
        check = compensation_check(rig, ident.model, *check_range_N, excitation.frequency_Hz, excitation.seed + 1)
        ident = replace(ident, compensation=Compensation(check.rms_N, check.max_N))
    return IdentifiedFeedforward(ident, loop, check)
