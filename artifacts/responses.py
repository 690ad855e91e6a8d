"""The compare stage's artifact: the study's step and trajectory run with its starting and its tuned gains.

:class:`ResponsesRecord` is ``responses/responses.json``: one :class:`ResponseRun` per gain set,
controller (PID alone, FF + PID) and reference, with the run's CSV beside it; the published
step numbers beside the simulated ones where the study declares them (:class:`ReproductionRow`);
and, where the feedforward compensates creep, FF + PID with the same model refitted without creep
(:class:`CreepRow`). The compare stage writes it, the report reads it.
"""

from __future__ import annotations

from typing import Any, ClassVar

from piezopreload.core.errors import ArtifactError
from piezopreload.core.records import Record, SavedArtifact, entry, hold_members, record
from piezopreload.models.metrics import Signal

__all__ = ["ResponseRun", "ReproductionRow", "CreepRow", "ResponsesRecord", "RESPONSE_FIGURES"]

KIND = "responses"
#: the figures of a run, None where they do not apply (a step that never settles)
RESPONSE_FIGURES = ("rise_s", "peak_s", "settling_s", "overshoot_N", "peak_command_V",
                    "tracking_rms_N", "tracking_max_N", "tracking_rms_after_change_N")


@record
class ResponseRun(Record):
    """One closed-loop run and its figures (None where a figure does not apply: a step that never settles)."""

    gains: str = entry('Which gains ("study", "tuned").')
    controller: str = entry('Which controller ("pid", "ff+pid").')
    reference: str = entry('Which reference ("step", "trajectory").')
    csv: str = entry("The run's CSV, relative to the output folder.")
    rise_s: float | None = entry("The step's rise time.", unit="s", default=None)
    peak_s: float | None = entry("The step's peak time.", unit="s", default=None)
    settling_s: float | None = entry("The step's settling time.", unit="s", default=None)
    overshoot_N: float | None = entry("The step's overshoot.", unit="N", default=None)
    peak_command_V: float | None = entry("The highest command.", unit="V", default=None)
    tracking_rms_N: float | None = entry("The RMS tracking error.", unit="N", default=None)
    tracking_max_N: float | None = entry("The largest tracking error.", unit="N", default=None)
    tracking_rms_after_change_N: float | None = entry("The RMS error outside the transport after each change.",
                                                      unit="N", default=None)


@record
class ReproductionRow(Record):
    """A published step number beside the study's gains' and the tuned gains' on the study's plant."""

    controller: str = entry('The controller ("pid", "ff+pid").')
    metric: str = entry('The step figure ("settling_s").')
    published: float = entry("The published value.")
    study: float | None = entry("The study's gains' value (None: it does not apply).", absent=None)
    tuned: float | None = entry("The tuned gains' value.", absent=None)


@record
class CreepRow(Record):
    """FF + PID with the feedforward's creep compensation (``creep``) or the same model refitted without it."""

    gains: str = entry('Which gains ("study", "tuned").')
    creep: bool = entry("Whether the feedforward compensated creep.")
    feedforward: str = entry("The feedforward's model.")
    reference: str = entry('Which reference ("step", "trajectory").')
    settling_s: float | None = entry("The step's settling time.", unit="s", default=None)
    overshoot_N: float | None = entry("The step's overshoot.", unit="N", default=None)
    tracking_rms_N: float | None = entry("The RMS tracking error.", unit="N", default=None)
    tracking_rms_after_change_N: float | None = entry("The RMS error outside the transport after each change.",
                                                      unit="N", default=None)


def _rows_or_null(rows: tuple[Record, ...]) -> list[dict[str, Any]] | None:
    return [r.to_dict() for r in rows] or None


@record
class ResponsesRecord(SavedArtifact):
    """The compare stage's artifact (see the module docstring)."""

    KIND: ClassVar[str] = KIND
    NOUN: ClassVar[str] = "the responses"
    AGAIN: ClassVar[str] = "run the compare stage again"

    runs: tuple[ResponseRun, ...] = entry("Every run: each gain set, controller and reference.")
    band_N: float = entry("The band the step times were read in.", unit="N", gt=0)
    signal: Signal = entry("The force the step times were read on.")
    seed: int = entry("The sensor noise's seed.")
    reproduction: tuple[ReproductionRow, ...] = entry("The published step numbers beside the simulated ones, where "
                                                      "the study declares them (null: none).", default=(),
                                                      absent=(), required=True, write=_rows_or_null)
    creep_effect: tuple[CreepRow, ...] = entry("FF + PID with and without the creep compensation, where the "
                                               "feedforward has creep (null: none).", default=(), absent=(),
                                               write=_rows_or_null)
    inputs: dict[str, Any] = entry("The inputs' hashes.", default={}, required=True)

    def __post_init__(self) -> None:
        hold_members(self)

    def run(self, gains: str, controller: str, reference: str) -> ResponseRun:
        """The run of ``gains`` with ``controller`` on ``reference``.

        Parameters
        ----------
        gains, controller, reference : str
            The run's gains ("study", "tuned"), controller ("pid", "ff+pid") and reference ("step", "trajectory").

        Returns
        -------
        ResponseRun
            The run.

        Raises
        ------
        ArtifactError
            Where the record holds no such run.
        """
        for r in self.runs:
            if (r.gains, r.controller, r.reference) == (gains, controller, reference):
                return r
        raise ArtifactError(f"the responses hold no run of {gains} {controller} on the {reference}")
