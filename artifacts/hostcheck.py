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
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from piezopreload.core.errors import ArtifactError

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["HostCheck", "Criterion", "HostFacts", "BIN_EDGES_S"]

#: the histogram's bin edges (s): roughly three per decade from 1 us to 100 ms, then everything later
BIN_EDGES_S = (0.0, 1e-6, 2e-6, 5e-6, 1e-5, 2e-5, 5e-5, 1e-4, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3, 1e-2, 2e-2, 5e-2, 1e-1,
               math.inf)


@dataclass(frozen=True)
class Criterion:
    """One pass/fail criterion: its name, whether it passed, the words with the numbers."""

    name: str
    passed: bool
    text: str


@dataclass(frozen=True)
class HostFacts:
    """What the host is, as far as a real-time loop cares (each a sentence; ``None`` where not found)."""

    kernel: str
    rt_kernel: bool
    preemption: str
    sched_fifo: str
    memory_locked: str
    cpu_governor: str
    virtualisation: str
    isolated_cpus: str
    cpus: int


def _need(doc: dict[str, Any], key: str, kind: Any, shown: str) -> Any:
    if key not in doc:
        raise ArtifactError(f"{shown}: field '{key}' is missing")
    value = doc[key]
    if kind is float:
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise ArtifactError(f"{shown}: field '{key}' must be a finite number, got {value!r}")
        return float(value)
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ArtifactError(f"{shown}: field '{key}' must be a whole number, got {value!r}")
        return value
    if not isinstance(value, kind):
        raise ArtifactError(f"{shown}: field '{key}' must be {getattr(kind, '__name__', kind)}, got {value!r}")
    return value


@dataclass(frozen=True, eq=False)
class HostCheck:
    """A host check (see the module docstring); times in seconds.

    ``lateness_*`` describe every wake-up; ``waited_p99_s`` the wake-ups that waited for their
    deadline (not those catching up after one later than a period). ``missed`` counts the
    wake-ups later than the budget (``budget_s``: the period less the controller step's p99
    compute time), which would have missed their deadline. ``verdict`` is ``pass`` when every
    criterion passed. ``lateness_s`` (the samples, for :meth:`plot`) is kept in memory only.
    """

    seconds: float
    rate_Hz: float
    samples: int
    lateness_p50_s: float
    lateness_p99_s: float
    lateness_p999_s: float
    lateness_max_s: float
    waited_p99_s: float
    missed: int
    step_p99_s: float
    step_max_s: float
    step_what: str
    budget_s: float
    stall_limit_s: float | None
    histogram_counts: tuple[int, ...]
    facts: HostFacts
    criteria: tuple[Criterion, ...]
    findings: tuple[str, ...]
    lateness_s: np.ndarray | None = field(default=None, repr=False)

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
        out = {k: v for k, v in asdict(self).items() if k not in ("lateness_s", "criteria", "facts")}
        out["histogram_counts"] = list(self.histogram_counts)
        out["histogram_edges_s"] = [e if math.isfinite(e) else None for e in BIN_EDGES_S]
        out["findings"] = list(self.findings)
        out["facts"] = asdict(self.facts)
        out["criteria"] = [asdict(c) for c in self.criteria]
        out["verdict"] = self.verdict
        out["period_s"] = self.period_s
        return out

    @classmethod
    def from_dict(cls, doc: Any, shown: str = "the host check") -> HostCheck:
        """The inverse of :meth:`to_dict`; an :class:`ArtifactError` names the field that is missing or wrong."""
        if not isinstance(doc, dict):
            raise ArtifactError(f"{shown}: expected an object")
        numbers = {k: _need(doc, k, float, shown) for k in (
            "seconds", "rate_Hz", "lateness_p50_s", "lateness_p99_s", "lateness_p999_s", "lateness_max_s",
            "waited_p99_s", "step_p99_s", "step_max_s", "budget_s")}
        limit = doc.get("stall_limit_s")
        counts = _need(doc, "histogram_counts", list, shown)
        if len(counts) != len(BIN_EDGES_S) - 1 or not all(isinstance(c, int) and c >= 0 for c in counts):
            raise ArtifactError(f"{shown}: field 'histogram_counts' must hold {len(BIN_EDGES_S) - 1} counts")
        facts = _need(doc, "facts", dict, shown)
        try:
            host = HostFacts(**facts)
            criteria = tuple(Criterion(**c) for c in _need(doc, "criteria", list, shown))
        except TypeError as exc:
            raise ArtifactError(f"{shown}: field 'facts' or 'criteria' is not valid: {exc}") from None
        return cls(samples=_need(doc, "samples", int, shown), missed=_need(doc, "missed", int, shown),
                   step_what=_need(doc, "step_what", str, shown),
                   stall_limit_s=None if limit is None else _need(doc, "stall_limit_s", float, shown),
                   histogram_counts=tuple(counts), facts=host, criteria=criteria,
                   findings=tuple(str(f) for f in _need(doc, "findings", list, shown)), **numbers)

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
