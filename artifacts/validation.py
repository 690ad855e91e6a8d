"""The Monte Carlo validation: its criteria, every plant's metrics, their statistics and the verdict.

One type, :class:`ValidationResult`, is what :func:`piezopreload.tuning.validate.validate`
returns, what a gain set carries (``gain_set.validation``), what ``validation.json`` holds (with
the gain set's hash and the inputs: :meth:`ValidationResult.save`, :meth:`ValidationResult.load`)
and what the report reads. Its statistics are attributes: ``result.worst.settling_s``,
``result.p95.overshoot_N``; its limits are :class:`~piezopreload.artifacts.requirements.Requirement`
values (``result.requirements``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from piezopreload.artifacts.requirements import Requirement, Sense
from piezopreload.core.records import Checked, Record, SavedArtifact, entry, record
from piezopreload.models.closedloop import PAPER_BAND_N
from piezopreload.models.metrics import Signal

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = ["Criteria", "Metrics", "Failure", "ValidationResult", "METRICS"]

#: the metrics evaluated on every plant, in their order
METRICS = ("rise_s", "settling_s", "settling_measured_s", "overshoot_N", "tracking_rms_N", "saturated_fraction",
           "tracking_rms_all_N", "tracking_max_N", "peak_voltage_V")

#: each limit of the criteria: the metric it bounds and its name in words
_LIMITS = {"settling_max_s": ("settling_s", "worst settling time", "s"),
           "overshoot_max_N": ("overshoot_N", "worst overshoot", "N"),
           "tracking_rms_max_N": ("tracking_rms_N", "worst tracking RMS after the changes", "N"),
           "peak_voltage_max_V": ("peak_voltage_V", "highest command", "V")}


@record
class Criteria(Checked, Record):
    """What every plant of the validation set must meet: a study's ``[validation]`` table (its keys, with the error
    band from ``[simulation]``), over ``plants`` Monte Carlo plants drawn with ``seed``.

    * ``settling_max_s``: the step's settling time into ``band_N``, read on ``signal``: the
      true force by default. The sensor's noise peaks near 0.9-1.1 N over a few thousand
      samples, so on the measured force a single spike decides whether a response that sits
      0.5 N inside the band "settles"; that settling time is reported beside it
      (``settling_measured_s``), as the paper read it.
    * ``overshoot_max_N``: the step's overshoot of the true force, for the same reason.
    * ``tracking_rms_max_N``: the trajectory's RMS error outside ``tracking_after_change_s``
      after each of its jumps (the transport no controller avoids) and outside the samples where
      the command sits at a limit of its range, where the plant cannot reach the reference at
      all, which no gains can change. ``saturated_fraction`` reports how much of each trajectory
      that left out, and the RMS over the whole trajectory is reported beside it
      (``tracking_rms_all_N``).
    * ``peak_voltage_max_V``: the command over both: the headroom the loop keeps below the controller's
      clamp (``u_max_V``). None: no such requirement (a limit at or above the clamp could not fail; a study
      that sets one is refused).
    """

    NOUN: ClassVar[str] = "the criteria"
    CLOSED: ClassVar[bool] = True
    #: the fields that are limits on a metric (a study's [validation] gives them)
    LIMITS: ClassVar[tuple[str, ...]] = tuple(_LIMITS)

    settling_max_s: float = entry("The worst plant's longest settling time.", unit="s", gt=0, default=0.60)
    overshoot_max_N: float = entry("The worst plant's largest overshoot.", unit="N", gt=0, default=PAPER_BAND_N)
    tracking_rms_max_N: float = entry("The worst plant's largest RMS tracking error after the changes.", unit="N",
                                      gt=0, default=1.0)
    peak_voltage_max_V: float | None = entry("The highest command over both references: the headroom the loop keeps "
                                             "below the controller's clamp (None: no such requirement; the clamp "
                                             "bounds the command, and a limit at or above it could not fail).",
                                             unit="V", gt=0, default=None)
    band_N: float = entry("The settling band around the step's final level.", unit="N", gt=0, default=PAPER_BAND_N)
    signal: Signal = entry("The force the step times are read on: the true force or the measured one.",
                           default=Signal.FORCE)
    tracking_after_change_s: float = entry("The time after each jump of the trajectory its RMS leaves out.",
                                           unit="s", ge=0, default=0.1)

    plants: int = entry("The Monte Carlo plants the criteria are checked over (the validation record states its own "
                        "count; not stored here).", ge=1, le=100_000, default=200, stored=False)
    seed: int | None = entry("The Monte Carlo draw's seed (None: a study's [simulation] seed).", ge=0, default=None,
                             stored=False)
    workers: int | None = entry("Local worker processes that check them (None: the CPU count).", ge=1, default=None,
                                stored=False)

    def limits(self) -> dict[str, float]:
        """Each bounded metric's limit (``{"settling_s": 0.6, ...}``); a limit not set (the peak command's) is left
        out."""
        return {metric: float(getattr(self, key)) for key, (metric, _, _) in _LIMITS.items()
                if getattr(self, key) is not None}

    def failures(self, metrics: dict[str, NDArray[np.float64]]) -> tuple[Failure, ...]:
        """One entry per plant and criterion it misses (a NaN, a step that never settled, misses)."""
        out: list[Failure] = []
        for metric, limit in self.limits().items():
            values = metrics[metric]
            bad = np.flatnonzero(~(values <= limit))
            out += [Failure(int(i), metric, _finite_or_none(values[i]), limit) for i in bad]
        return tuple(out)


@record
class Metrics(Record):
    """One statistic (the worst, a percentile, the best) of every metric over the plants; None where none is finite."""

    rise_s: float | None = entry("The step's rise time.", unit="s")
    settling_s: float | None = entry("The step's settling time into the band, on the criteria's signal.", unit="s")
    settling_measured_s: float | None = entry("The step's settling time on the measured force.", unit="s")
    overshoot_N: float | None = entry("The step's overshoot of the true force.", unit="N")
    tracking_rms_N: float | None = entry("The trajectory's RMS error after its changes, off the command's limits.",
                                         unit="N")
    saturated_fraction: float | None = entry("The share of the trajectory the command spent at a limit.")
    tracking_rms_all_N: float | None = entry("The trajectory's RMS error over all of it.", unit="N")
    tracking_max_N: float | None = entry("The trajectory's largest error.", unit="N")
    peak_voltage_V: float | None = entry("The highest command over both references.", unit="V")


@record
class Failure(Record):
    """A plant that missed a criterion."""

    plant: int = entry("The plant's index in the set (0: the nominal plant).", ge=0)
    metric: str = entry("The metric it missed (one of :data:`METRICS`).")
    value: float | None = entry("Its value (None: the step never settled).")
    limit: float = entry("The criterion's limit.")


def _finite_or_none(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _of(values: NDArray[np.float64], how: str) -> float:
    w = np.where(np.isnan(values), np.inf, values)  # a NaN (a step that never settled) ranks worst
    if how == "worst":
        return float(np.max(w))
    if how == "best":
        return float(np.min(w))
    return float(np.percentile(w, 95.0 if how == "p95" else 50.0))


def _statistic(metrics: dict[str, NDArray[np.float64]], how: str) -> Metrics:
    return Metrics(**{key: _finite_or_none(_of(metrics[key], how)) for key in METRICS})


def _metrics_from(doc: Any) -> dict[str, NDArray[np.float64]]:
    """Every metric's values, one per plant (null: a step that never settled, as NaN)."""
    if not isinstance(doc, dict):
        raise ValueError(f"expected an object of {', '.join(METRICS)}")
    out = {}
    for key in METRICS:
        values = doc.get(key)
        if not isinstance(values, list) or any(
                x is not None and (isinstance(x, bool) or not isinstance(x, int | float)) for x in values):
            raise ValueError(f"metrics.{key} must be a list of numbers or nulls")
        out[key] = np.array([np.nan if x is None else x for x in values], dtype=np.float64)
    return out


def _metrics_to(metrics: dict[str, NDArray[np.float64]]) -> dict[str, list[float | None]]:
    return {k: [_finite_or_none(x) for x in metrics[k]] for k in METRICS}


@record(eq=False)
class ValidationResult(SavedArtifact):
    """The gains run on a Monte Carlo set of nonlinear plants: every plant's metrics and the verdict."""

    KIND: ClassVar[str] = "validation"
    NOUN: ClassVar[str] = "the validation"
    AGAIN: ClassVar[str] = "validate the gain set again"

    metrics: dict[str, NDArray[np.float64]] = entry(
        "Every metric of :data:`METRICS`, one value per plant (the nominal plant first; NaN: a step that never "
        "settled).", read=_metrics_from, write=_metrics_to, takes=f"an object of lists ({', '.join(METRICS)})")
    criteria: Criteria = entry("What every plant had to meet.")
    n_plants: int = entry("The set's size.", ge=1)
    seed: int = entry("The seed of its draw (and of the sensor noise).")
    spread: dict[str, float] = entry("The relative standard deviations the plants were drawn with.")
    seconds: float = entry("How long it took.", unit="s", default=0.0)
    workers: str = entry('Where it ran ("inline", "2 local processes", "dask tcp://...").', default="inline")
    gain_set_sha256: str | None = entry("The gain set validated (set when it is saved as ``validation.json``).",
                                        default=None, required=True)
    inputs: dict[str, Any] = entry("The inputs' hashes (``validation.json``).", default={}, required=True)

    def __post_init__(self) -> None:
        missing = [k for k in METRICS if k not in self.metrics]
        if missing:
            raise ValueError(f"ValidationResult.metrics lacks {', '.join(missing)}")
        bad = [k for k in METRICS if np.shape(self.metrics[k]) != (self.n_plants,)]
        if bad:
            raise ValueError(f"ValidationResult.metrics['{bad[0]}'] must hold one value per plant ({self.n_plants}), "
                             f"got shape {np.shape(self.metrics[bad[0]])}")

    # ---- the verdict ---------------------------------------------------------------------------
    @property
    def failures(self) -> tuple[Failure, ...]:
        """Every (plant, criterion) missed."""
        return self.criteria.failures(self.metrics)

    @property
    def passed(self) -> bool:
        """Whether every plant met every criterion."""
        return not self.failures

    @property
    def failed_plant_count(self) -> int:
        """How many plants failed at least one criterion."""
        return len({f.plant for f in self.failures})

    @property
    def worst(self) -> Metrics:
        """Each metric's worst value over the plants, the largest (None where a step never settled: it ranks worst)."""
        return _statistic(self.metrics, "worst")

    @property
    def p95(self) -> Metrics:
        """Each metric's 95th percentile over the plants (a step that never settled counts as infinite)."""
        return _statistic(self.metrics, "p95")

    @property
    def median(self) -> Metrics:
        """Each metric's median over the plants (a step that never settled counts as infinite)."""
        return _statistic(self.metrics, "p50")

    @property
    def best(self) -> Metrics:
        """Each metric's best value over the plants (the smallest)."""
        return _statistic(self.metrics, "best")

    @property
    def requirements(self) -> tuple[Requirement, ...]:
        """Each limit beside the worst plant's value (a step that never settled counts as infinitely late)."""
        worst = self.worst
        out = []
        for key, (metric, name, unit) in _LIMITS.items():
            if getattr(self.criteria, key) is None:  # no such requirement (the peak command's headroom, not set)
                continue
            value = getattr(worst, metric)
            limit = float(getattr(self.criteria, key))
            if value is None:  # never settled, or no finite value: a miss by more than any number
                value = 1e9 * max(abs(limit), 1.0)
            out.append(Requirement(f"{name} over {self.n_plants} Monte Carlo plants", float(value), limit, unit,
                                   Sense.AT_MOST, f"[validation] {key}"))
        return tuple(out)

    def failed_plants(self, shown: int = 3) -> str:
        """``failed on N of M plants (the first failures)``: what a refusal says.

        Parameters
        ----------
        shown : int
            How many failures to quote (plant, metric, value and limit).

        Returns
        -------
        str
            ``failed on N of M plants (plant I: METRIC VALUE > LIMIT; ...)``.
        """
        first = "; ".join(f"plant {f.plant}: {f.metric} {f.value} > {f.limit:g}" for f in self.failures[:shown])
        return f"failed on {self.failed_plant_count} of {self.n_plants} plants ({first})"

    def headline(self) -> dict[str, float | None]:
        """The worst plant's settling time (and the 95th percentile's), overshoot, tracking error and voltage.

        Returns
        -------
        dict of str to float or None
            ``worst_settling_s`` and ``p95_settling_s`` (s), ``worst_overshoot_N`` and ``worst_tracking_rms_N`` (N),
            ``worst_peak_voltage_V`` (V); None where no plant's value is finite.
        """
        w = self.worst
        return {"worst_settling_s": w.settling_s, "p95_settling_s": self.p95.settling_s,
                "worst_overshoot_N": w.overshoot_N, "worst_tracking_rms_N": w.tracking_rms_N,
                "worst_peak_voltage_V": w.peak_voltage_V}

    def summary(self) -> dict[str, dict[str, float | None]]:
        """Every metric's worst, median, 95th percentile and best, by metric (as ``to_dict`` writes them).

        Returns
        -------
        dict of str to dict
            By metric (``settling_s``, ``overshoot_N``, ...), its ``worst``, ``p50``, ``p95`` and ``best`` over the
            plants, in the unit its name carries (None where not finite).
        """
        stats = {"worst": self.worst, "p50": self.median, "p95": self.p95, "best": self.best}
        return {k: {s: getattr(m, k) for s, m in stats.items()} for k in METRICS}

    # ---- the document ----------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The body of ``validation.json`` and of a gain set's ``validation`` field: the fields, the verdict, the
        statistics and the first 50 failures.

        Returns
        -------
        dict
            The document's object.
        """
        failures = self.failures
        return {**super().to_dict(), "passed": self.passed, "summary": self.summary(),
                "failures": [f.to_dict() for f in failures[:50]], "n_failures": len(failures)}

    def __repr__(self) -> str:
        verdict = "passed" if self.passed else f"failed on {self.failed_plant_count} plants"
        w = self.worst
        return (f"ValidationResult({verdict}, {self.n_plants} plants, seed {self.seed}; worst settling "
                f"{_show(w.settling_s, 's')}, overshoot {_show(w.overshoot_N, 'N')}, tracking RMS "
                f"{_show(w.tracking_rms_N, 'N')})")

    def _repr_html_(self) -> str:
        rows = "".join(
            f"<tr><td>{r.name}</td><td>{_show(r.value if r.value < 1e8 else None, r.unit)}</td>"
            f"<td>{r.limit:g} {r.unit}</td><td>{'met' if r.met else '<b>missed</b>'}</td></tr>"
            for r in self.requirements)
        return (f"<p><b>Monte Carlo validation</b>: {'passed' if self.passed else 'failed'} on {self.n_plants} plants "
                f"(seed {self.seed})</p>"
                f"<table><tr><th>limit</th><th>worst plant</th><th>limit</th><th>verdict</th></tr>{rows}</table>")

    def plot(self) -> Figure:
        """A Figure: the distributions of :meth:`draw_histograms`, one panel each.

        Returns
        -------
        matplotlib.figure.Figure
            One histogram per metric of :meth:`histogram_metrics` over the plants (finite values), its limit dashed
            where the criteria set one.
        """
        from matplotlib.figure import Figure

        fig = Figure(figsize=(10, 3), layout="constrained")
        self.draw_histograms(fig.subplots(1, len(self.histogram_metrics()), squeeze=False)[0])
        return fig

    def histogram_metrics(self) -> tuple[str, ...]:
        """The metrics :meth:`draw_histograms` draws.

        Returns
        -------
        tuple of str
            Settling time, overshoot and tracking RMS, and every other metric the criteria bound (the peak command
            when a limit is set).
        """
        bounded = tuple(m for m in self.criteria.limits() if m not in _HISTOGRAMS)
        return _HISTOGRAMS + bounded

    def draw_histograms(self, axes: Sequence[Axes], *, colour: str = "tab:blue",
                        limit_colour: str = "tab:red") -> list[Axes]:
        """Draw each metric of :meth:`histogram_metrics` over the plants on one of ``axes``: its limit dashed where
        the criteria set one, the count of plants ticked in whole numbers, and in each title how many plants it
        counts and how many never settled (a NaN, left out of the histogram).

        Parameters
        ----------
        axes : sequence of matplotlib Axes
            One per metric of :meth:`histogram_metrics`, in its order.
        colour, limit_colour : str
            The bars' colour and the limit's.

        Returns
        -------
        list of Axes
            The axes on which a limit is marked (each has a line labelled "limit", for a legend).
        """
        from matplotlib.ticker import MaxNLocator

        metrics = self.histogram_metrics()
        if len(axes) != len(metrics):
            raise ValueError(f"draw_histograms needs one axes per metric ({', '.join(metrics)}), got {len(axes)}")
        limits = self.criteria.limits()
        marked = []
        for ax, metric in zip(axes, metrics):
            raw = np.asarray(self.metrics[metric], float)
            values = raw[np.isfinite(raw)]
            never = raw.size - values.size
            ax.hist(values, bins=min(30, max(5, values.size // 5)), color=colour, alpha=0.8)
            if metric in limits:
                ax.axvline(limits[metric], color=limit_colour, ls="--", lw=0.9, label="limit")
                marked.append(ax)
            ax.set_xlabel(_AXIS_LABELS.get(metric, metric))
            ax.set_ylabel("plants")
            ax.yaxis.set_major_locator(MaxNLocator(integer=True))  # a count of plants
            ax.set_title(f"{values.size} plants" + (f", {never} never settled" if never else ""))
        return marked


#: the metrics every validation figure shows, bounded or not
_HISTOGRAMS = ("settling_s", "overshoot_N", "tracking_rms_N")
_AXIS_LABELS = {"settling_s": "settling time (s)", "overshoot_N": "overshoot (N)",
                "tracking_rms_N": "tracking RMS after changes (N)", "peak_voltage_V": "peak command (V)"}


def _show(x: float | None, unit: str) -> str:
    return "never" if x is None else f"{x:.3g} {unit}"
