"""Learning along a study's preload schedule: :class:`ScheduleLearning` (``study.learn_schedule(gains)``).

Each margin pass of the schedule (:func:`~piezopreload.steps.track_schedule`) learned on its own repeated
reference, and the schedule tracked with each pass's learned signal played. The pipeline's learn stage writes it
(:func:`~piezopreload.tuning.learning.save_passes`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from piezopreload.artifacts.learned import LearnedSignal
from piezopreload.design.system import SystemRun
from piezopreload.tuning.learning import LearnedWritten, LearningResult, save_passes

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["ScheduleLearning"]


def _before_learning(result: LearningResult) -> float:
    """A pass's RMS error before learning: without any learned correction (a warm-started pass's first trial already
    carries the pass before's)."""
    return float(result.info.get("before_learning_rms_N", np.max(result.history[0].tracking_rms_N)))


@dataclass(frozen=True, eq=False)
class ScheduleLearning:
    """Learning along the design's preload schedule (``study.learn_schedule(gains)``): each margin
    pass of the schedule learned on its own repeated reference (``passes``, one
    :class:`~piezopreload.tuning.learning.LearningResult` each), and the tracking of the schedule with each pass's
    learned signal played (``system``, the last pass's :class:`~piezopreload.design.system.SystemRun`).

    Parameters
    ----------
    system : SystemRun
        The schedule tracked with each pass's learned signal played.
    passes : tuple of LearningResult
        One learning per margin pass of the schedule, in order.
    """

    system: SystemRun
    passes: tuple[LearningResult, ...]

    @property
    def last(self) -> LearningResult:
        """The last pass's learning: the signal the schedule is played with."""
        return self.passes[-1]

    @property
    def before_learning_rms_N(self) -> float:
        """The last pass's RMS error before learning (the tuned loop with its feedforward and preview)."""
        return _before_learning(self.last)

    def save(self, folder: str | Path, gain_set_sha256: str | None,
             inputs: dict[str, Any] | None = None) -> LearnedWritten:
        """Write each pass's learned signal and ``learning.json`` (:func:`~piezopreload.tuning.learning.save_passes`)
        into ``folder``; returns the last pass's signal (``out``, what the rig plays) and its hash.

        Parameters
        ----------
        folder : str or Path
            The folder the files are written into.
        gain_set_sha256 : str or None
            The hash of the gain set the signals were learned with (None: unsaved gains).
        inputs : dict or None
            The hashes of the files the learning came from, by name (None: none).

        Returns
        -------
        LearnedWritten
            The last pass's learned signal's path and hash, and the path of ``learning.json``.
        """
        paths, _ = save_passes(list(self.passes), folder, gain_set_sha256, dict(inputs or {}))
        return LearnedWritten(str(paths["learned"]), LearnedSignal.load(paths["learned"]).content_sha256,
                              str(paths["learning"]))

    def to_dict(self) -> dict[str, Any]:
        """The last pass's learning (as a :class:`LearningResult`'s), each pass's figures and
        the schedule's tracking.

        Returns
        -------
        dict
            The last pass's :meth:`LearningResult.to_dict`, ``before_learning_rms_N`` (N), ``passes`` (each pass's
            margin in N and its RMS error before and after learning in N) and ``system``, the schedule's tracking
            (:meth:`SystemSummary.to_dict`).
        """
        return {**self.last.to_dict(), "before_learning_rms_N": self.before_learning_rms_N,
                "passes": [{"pass": k, "preload_margin_N": None if p is None else p.preload_margin_N,
                            "tracking_rms_N": r.tracking_rms_N,
                            "before_learning_rms_N": _before_learning(r)}
                           for k, (r, p) in enumerate(zip(self.passes, self._pass_records()), start=1)],
                "system": self.system.summary().to_dict()}

    def _pass_records(self) -> list[Any]:
        """The system's record of each learned pass (None for a pass the system did not run again)."""
        records: list[Any] = list(self.system.passes)
        return records + [None] * (len(self.passes) - len(records))

    def __repr__(self) -> str:
        return (f"ScheduleLearning({len(self.passes)} pass{'es' if len(self.passes) > 1 else ''}, margin "
                f"{self.system.margin_N:.1f} N: tracking RMS {self.last.tracking_rms_N:.2f} N after learning, "
                f"{self.before_learning_rms_N:.2f} N before; requirements met: {self.system.requirements_met})")

    def plot(self) -> Figure:
        """The error per iteration of each pass (left) and the schedule's tracking (the system run's figure is
        ``system.plot()``): a Figure.

        Returns
        -------
        matplotlib.figure.Figure
            The worst plant's RMS error of the true force (N, log scale) against the iteration, one line per pass.
        """
        from matplotlib.figure import Figure

        fig = Figure(figsize=(5.5, 3.6), layout="constrained")
        ax = fig.subplots()
        for k, result in enumerate(self.passes, start=1):
            ax.semilogy([h.iteration for h in result.history],
                        [float(np.max(np.atleast_1d(h.tracking_rms_N))) for h in result.history], "o-",
                        label=f"pass {k}")
        ax.set(xlabel="iteration", ylabel="RMS error of the true force (N)",
               title="learning along the preload schedule, each margin pass")
        ax.legend(fontsize="small")
        return fig
