"""The host check's result: how late this host wakes a thread at the loop's priority and rate,
against the loop's budget.

:func:`piezopreload.rig.hostcheck.check_host` measures it (``piezopreload rig check``, and the
check ``rig run --realtime`` and ``rig serve`` make before arming); a run's sidecar keeps it
(:class:`~piezopreload.artifacts.rigrun.RigRunRecord`). :class:`HostCheck` holds the figures,
the criteria with their verdicts, the host's facts that matter for a real-time loop, and
draws itself (:meth:`HostCheck.plot`, :meth:`HostCheck.histogram_text`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from piezopreload.core.records import Record, entry, record

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["HostCheck", "Criterion", "HostFacts", "BIN_EDGES_S"]

#: the histogram's bin edges (s): roughly three per decade from 1 us to 100 ms, then everything later
BIN_EDGES_S = (0.0, 1e-6, 2e-6, 5e-6, 1e-5, 2e-5, 5e-5, 1e-4, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3, 1e-2, 2e-2, 5e-2, 1e-1,
               math.inf)


@record
class Criterion(Record):
    """One pass/fail criterion of the host check."""

    name: str = entry('The criterion ("rate", "stall").')
    passed: bool = entry("Whether it passed.")
    text: str = entry("The criterion in words, with its numbers.")


@record
class HostFacts(Record):
    """What the host is, as far as a real-time loop cares (each a sentence)."""

    kernel: str = entry("The kernel's name and release.")
    rt_kernel: bool = entry("Whether it is a real-time (PREEMPT_RT) kernel.")
    preemption: str = entry("The kernel's preemption model.")
    sched_fifo: str = entry("Whether the loop's thread got SCHED_FIFO.")
    memory_locked: str = entry("Whether its memory was locked.")
    cpu_governor: str = entry("The CPUs' frequency governor.")
    virtualisation: str = entry("The hypervisor, or bare metal.")
    isolated_cpus: str = entry("The CPUs isolated from the scheduler.")
    cpus: int = entry("The CPUs.", ge=1)


@record(eq=False)
class HostCheck(Record):
    """A host check (see the module docstring); times in seconds.

    ``lateness_*`` describe every wake-up; ``waited_p99_s`` the wake-ups that waited for their
    deadline (not those catching up after one later than a period). ``missed`` counts the
    wake-ups later than the budget (``budget_s``: the period less the controller step's p99
    compute time), which would have missed their deadline. ``verdict`` is ``pass`` when every
    criterion passed. ``lateness_s`` (the samples, for :meth:`plot`) is kept in memory only.
    """

    NOUN: ClassVar[str] = "the host check"

    seconds: float = entry("How long it measured.", unit="s")
    rate_Hz: float = entry("The loop's rate it woke at.", unit="Hz", gt=0)
    samples: int = entry("The wake-ups.", ge=0)
    lateness_p50_s: float = entry("The median lateness of a wake-up.", unit="s")
    lateness_p99_s: float = entry("Its 99th percentile.", unit="s")
    lateness_p999_s: float = entry("Its 99.9th percentile.", unit="s")
    lateness_max_s: float = entry("The latest wake-up's lateness.", unit="s")
    waited_p99_s: float = entry("The 99th percentile of the wake-ups that waited for their deadline.", unit="s")
    missed: int = entry("The wake-ups later than the budget.", ge=0)
    step_p99_s: float = entry("The controller step's 99th-percentile compute time.", unit="s")
    step_max_s: float = entry("Its longest.", unit="s")
    step_what: str = entry("Which controller step was timed.")
    budget_s: float = entry("The period less the step's p99 compute time.", unit="s")
    stall_limit_s: float | None = entry("The stall interlock's limit it was judged against.", unit="s", absent=None)
    histogram_counts: tuple[int, ...] = entry("The wake-ups per bin of :data:`BIN_EDGES_S`.", ge=0,
                                              size=len(BIN_EDGES_S) - 1)
    facts: HostFacts = entry("What the host is.")
    criteria: tuple[Criterion, ...] = entry("The criteria and their verdicts.")
    findings: tuple[str, ...] = entry("What stands in a real-time loop's way, in words.")
    lateness_s: np.ndarray | None = entry("Every wake-up's lateness (in memory only).", unit="s", stored=False,
                                          default=None)

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_Hz

    @property
    def verdict(self) -> str:
        return "pass" if all(c.passed for c in self.criteria) else "fail"

    @property
    def passed(self) -> bool:
        return self.verdict == "pass"

    def __repr__(self) -> str:
        return (f"HostCheck({self.verdict}: {self.samples} wake-ups at {self.rate_Hz:g} Hz, lateness p99 "
                f"{self.lateness_p99_s * 1e6:.0f} us, max {self.lateness_max_s * 1e3:.2f} ms, {self.missed} missed)")

    # ---- the document ---------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The check's figures, the histogram's edges, its verdict and its period.

        Returns
        -------
        dict
            Its object.
        """
        return {**super().to_dict(), "histogram_edges_s": [e if math.isfinite(e) else None for e in BIN_EDGES_S],
                "verdict": self.verdict, "period_s": self.period_s}

    # ---- pictures -------------------------------------------------------------------------------
    def histogram_text(self, width: int = 40) -> str:
        """The lateness histogram as text: one line per bin that holds a wake-up, a bar of ``#`` on a log scale."""
        counts = np.asarray(self.histogram_counts)
        top = max(1, int(counts.max()))
        lines = []
        for j, n in enumerate(counts):
            if n == 0:
                continue
            lo, hi = BIN_EDGES_S[j], BIN_EDGES_S[j + 1]
            bar = "#" * max(1, int(round(width * math.log1p(n) / math.log1p(top))))
            label = f"{_us(lo):>9} .. {_us(hi) if math.isfinite(hi) else '':<9}"
            lines.append(f"  {label} {n:>8} {bar}")
        return "\n".join(lines)

    def plot(self) -> Figure:
        """The lateness histogram on a log axis with the budget and the stall limit marked: a Figure."""
        from matplotlib.figure import Figure

        fig = Figure(figsize=(7.0, 3.6), layout="constrained")
        ax = fig.subplots()
        late = self.lateness_s
        if late is not None and late.size:
            edges = np.logspace(-7, max(-1.0, math.log10(max(float(late.max()), 1e-7)) + 0.1), 60)
            ax.hist(np.clip(late, 1e-7, None), bins=edges.tolist(), color="0.35")
        else:  # read back from a file: the coarse bins
            edges = np.asarray([max(e, 1e-7) for e in BIN_EDGES_S[:-1]] + [1.0])
            ax.stairs(self.histogram_counts, edges, fill=True, color="0.35")
        ax.set(xscale="log", yscale="log", xlabel="wake-up lateness (s)", ylabel="wake-ups",
               title=f"{self.samples} wake-ups at {self.rate_Hz:g} Hz: {self.verdict}")
        ax.axvline(self.budget_s, color="tab:orange", ls="--", label=f"budget {self.budget_s * 1e6:.0f} us")
        if self.stall_limit_s is not None:
            held = self.stall_limit_s - self.period_s
            ax.axvline(held, color="tab:red", ls="--", label=f"stall limit less a period {held * 1e3:.1f} ms")
        ax.legend(fontsize="small")
        return fig


def _us(seconds: float) -> str:
    if seconds >= 1e-3:
        return f"{seconds * 1e3:g} ms"
    return f"{seconds * 1e6:g} us"
