"""What the study's simulating steps return: :class:`StudyRun` (:func:`piezopreload.steps.simulate`) and
:class:`StudyReproduction` (:func:`piezopreload.steps.reproduce`). The tune step returns the tuning artifact itself,
:class:`~piezopreload.artifacts.tuning.TuningResult`.

Each result carries its numbers, ``to_dict()`` (what ``--json`` prints or the artifact
holds) and ``plot()`` (a matplotlib Figure, no pyplot state). The domain computations are the
floors': the tuning (:mod:`piezopreload.tuning.pid`, its record :mod:`piezopreload.artifacts.tuning`), the comparison
(:mod:`piezopreload.tuning.compare`), the verdict (:mod:`piezopreload.tuning.verdict`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from piezopreload.artifacts.gainset import GainsTable
from piezopreload.artifacts.manifest import StudyRef
from piezopreload.core.errors import InputError
from piezopreload.models.closedloop import ClosedLoopRun
from piezopreload.models.controller import PIDGains
from piezopreload.models.metrics import Signal, StepMetrics, run_numbers
from piezopreload.tuning.compare import PublishedRow
from piezopreload.tuning.feedforward import FeedforwardInfo

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["StudyRun", "SimulationInfo", "StudyReproduction"]

_STEP_KEYS = ("rise_s", "peak_s", "settling_s", "overshoot_N")
_TRACK_KEYS = ("tracking_rms_N", "tracking_max_N")


_STUDY = object()  # step_metrics' default: the study's band and signal


@dataclass(frozen=True)
class SimulationInfo:
    """What a study's simulation ran: the study, the controller and the reference, the gains and where they came from
    (``gains_source``; a gain set's ``gains_status``), the feedforward (None: the PID alone), the sample period, and
    the study's published numbers for this run (``published``: its source and the numbers by name; None where it
    declares none).

    Parameters
    ----------
    study : StudyRef
        Which study.
    controller : str
        ``pid`` or ``ff+pid``.
    reference : str
        ``step`` or ``trajectory``.
    gains : PIDGains
        The gains that ran.
    gains_source : str
        Where they came from, in words (or the gain set's file).
    sample_period_s : float
        The loop's sample period (s).
    feedforward : FeedforwardInfo or None
        The feedforward (None: the PID alone).
    gains_status : str or None
        A gain set's status.
    published : dict or None
        The study's published numbers for this run, with their source.
    """

    study: StudyRef
    controller: str
    reference: str
    gains: PIDGains
    gains_source: str
    sample_period_s: float
    feedforward: FeedforwardInfo | None = None
    gains_status: str | None = None
    published: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        """What ran, as ``simulate --json`` prints it.

        Returns
        -------
        dict
            ``study``, ``controller``, ``reference``, ``gains`` (the gains' table with their source and status),
            ``feedforward`` (None without one), ``sample_period_s`` (s) and ``published``.
        """
        source = {"source": self.gains_source, **({} if self.gains_status is None else {"status": self.gains_status})}
        return {"study": self.study.to_dict(), "controller": self.controller, "reference": self.reference,
                "gains": {**GainsTable.from_value(self.gains).to_dict(), **source},
                "feedforward": None if self.feedforward is None else self.feedforward.to_dict(),
                "sample_period_s": self.sample_period_s, "published": self.published}


@dataclass(frozen=True, eq=False, kw_only=True)
class StudyRun(ClosedLoopRun):
    """A closed-loop run of one plant, scored as its study says (``band_N``, ``signal``); ``info`` says what ran.

    Parameters
    ----------
    t_s, reference_N, force_N, measured_N, command_V, voltage_V, p_V, i_V, d_V, ff_V, reference, seed, engine
        As :class:`~piezopreload.models.closedloop.ClosedLoopRun` has them.
    band_N : float
        The study's error band of the step metrics (N).
    signal : Signal
        The signal the study scores (the true force or the measured one).
    info : SimulationInfo
        What ran: the study, the controller, the reference, the gains, the feedforward, the sample period and the
        study's published numbers for the run.
    """

    band_N: float
    signal: Signal
    info: SimulationInfo

    def step_metrics(self, band_N: Any = _STUDY, *, which: int = 1, signal: Signal | str | None = None) -> StepMetrics:
        """Rise, peak and settling time and overshoot of the reference's ``which``-th change, in the study's band
        on the study's signal unless given (``band_N=None``: the 10-90 % / 2 % definitions).

        Parameters
        ----------
        band_N : float or None
            The settling band, in N (default: the study's); None: the conventional 2 % band and 10-90 % rise.
        which : int
            Which change of the reference, from 1.
        signal : Signal, str or None
            The signal scored, ``force_N`` or ``measured_N`` (None: the study's).

        Returns
        -------
        StepMetrics
            The step's rise, peak and settling times (s) and overshoot (N).
        """
        m = super().step_metrics(self.band_N if band_N is _STUDY else band_N, which=which, signal=signal or self.signal)
        if not isinstance(m, StepMetrics):  # pragma: no cover - a study's run is one plant
            raise InputError("step_metrics of a batch: index the batch first")
        return m

    def to_dict(self) -> dict[str, Any]:
        """What ``piezopreload simulate --json`` prints: what ran, the step numbers, tracking, and the study's published
        numbers for this run where it declares them (``published``: None otherwise).

        Returns
        -------
        dict
            :meth:`SimulationInfo.to_dict`'s keys, ``reference_levels_N``, ``band_N``, ``signal``, ``seed``, ``samples``
            and :meth:`numbers`.
        """
        return {
            **self.info.to_dict(), "reference_levels_N": self.reference.levels_N.tolist(), "band_N": self.band_N,
            "signal": str(self.signal), "seed": self.seed, "samples": int(self.t_s.size), **self.numbers(),
        }

    def numbers(self) -> dict[str, float | None]:
        """The step numbers (rise, peak, settling, overshoot) and the peak command, and over the trajectory the
        tracking errors, in the study's band on its signal (None: a time never reached).

        Returns
        -------
        dict of str to float or None
            The step's times (s) and overshoot (N), ``peak_command_V`` (V) and, over a trajectory, the tracking errors
            (N).
        """
        numbers = run_numbers(self, self.band_N, self.signal)
        tracking = self.info.reference == "trajectory"
        return {k: numbers[k] for k in (*_STEP_KEYS, "peak_command_V", *(_TRACK_KEYS if tracking else ()))}

    def plot(self) -> Figure:
        """Reference and force (top), command and amplifier voltage (bottom): a Figure.

        Returns
        -------
        matplotlib.figure.Figure
            The reference and the force (N) above, the command and the amplifier's voltage (V) below, against time.
        """
        from piezopreload.reports import figures  # matplotlib only when drawing

        title = (f"{self.info.controller.replace('ff+pid', 'FF + PID').replace('pid', 'PID')}, "
                 f"{self.info.reference}")
        return figures.closed_loop(self.columns(), self.band_N, self.signal, title)


@dataclass(frozen=True)
class StudyReproduction:
    """A study's published step numbers beside its simulation's, with the PID alone and with the feedforward
    (:meth:`Study.reproduce <piezopreload.study.Study.reproduce>`): the study, its gains (and how its
    ``[controller]`` was read), the step, the band, the signal judged, one
    :class:`~piezopreload.tuning.compare.PublishedRow` per controller and
    metric, the overshoot per controller, the feedforward's fit and the noise realisations behind each number.

    Parameters
    ----------
    study : StudyRef
        Which study.
    gains : PIDGains
        The study's gains.
    read_as : str
        How its ``[controller]`` was read (the time unit of Ti and Td).
    band_N : float
        The settling band (N).
    signal : Signal
        The signal the step numbers are read on.
    published : str
        Where the published numbers come from.
    step_levels_N : tuple of float
        The step's levels (N).
    rows : tuple of PublishedRow
        Each published number beside the simulated one, one row per controller and metric.
    overshoot_N : dict of str to float
        The simulated overshoot per controller (N).
    feedforward_fit : dict of str to float
        The identified P-I model's fit error, in % of the force span (``rms_pct``, ``max_pct``).
    repeats : int
        Over how many noise realisations each simulated number is the median.
    seconds : float
        The time the simulations took (s).
    """

    study: StudyRef
    gains: PIDGains
    read_as: str
    band_N: float
    signal: Signal
    published: str
    step_levels_N: tuple[float, ...]
    rows: tuple[PublishedRow, ...]
    overshoot_N: dict[str, float]
    feedforward_fit: dict[str, float]
    repeats: int
    seconds: float

    @property
    def all_within_25pct(self) -> bool:
        """Whether every reproduced figure is within 25 % of the published one."""
        return all(r.within_25pct for r in self.rows)

    def row(self, controller: str, metric: str) -> PublishedRow:
        """The row of ``controller`` (``pid``, ``ff+pid``) and ``metric`` (``rise_s``, ``peak_s``, ``settling_s``).

        Parameters
        ----------
        controller : str
            ``pid`` or ``ff+pid``.
        metric : str
            ``rise_s``, ``peak_s`` or ``settling_s``.

        Returns
        -------
        PublishedRow
            The published and the simulated number (s; None: never reached), their ratio, whether it lies within
            25 % of the published one, and its range over the noise realisations.

        Raises
        ------
        KeyError
            Where no row has that controller and metric; the message lists the rows.
        """
        for r in self.rows:
            if (r.controller, r.metric) == (controller, metric):
                return r
        raise KeyError(f"no row for {controller!r}, {metric!r}: the rows are "
                       f"{', '.join(f'{r.controller}/{r.metric}' for r in self.rows)}")

    def to_dict(self) -> dict[str, Any]:
        """What ``reproduce --json`` prints.

        Returns
        -------
        dict
            ``study``, ``gains`` (and how they were read), ``band_N``, ``signal``, ``published``, ``step``,
            ``feedforward_fit`` (% of the span), ``rows``, ``overshoot_N`` (N, per controller),
            ``all_within_25pct``, ``repeats`` and ``seconds``.
        """
        return {"study": self.study.to_dict(),
                "gains": {**GainsTable.from_value(self.gains).to_dict(), "read_as": self.read_as},
                "band_N": self.band_N, "signal": str(self.signal), "published": self.published,
                "step": " -> ".join(f"{x:g}" for x in self.step_levels_N) + " N",
                "feedforward_fit": dict(self.feedforward_fit), "rows": [r.to_dict() for r in self.rows],
                "overshoot_N": dict(self.overshoot_N), "all_within_25pct": self.all_within_25pct,
                "repeats": self.repeats, "seconds": self.seconds}

    def __repr__(self) -> str:
        within = sum(r.within_25pct for r in self.rows)
        return (f"StudyReproduction({self.study.name!r}: {within} of {len(self.rows)} step numbers within 25 % of "
                f"{self.published}; {self.repeats} noise draw(s))")
