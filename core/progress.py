"""Progress of a long step: stage lines, messages and progress bars, and the one type every floor takes for it.

Every function of every floor that reports progress takes ``progress`` of one type, :data:`ProgressLike`: a
function given each line (``print``, a logger's ``info``), or a :class:`Progress` (stage lines, indented messages
and bars on a stream). None gives nothing (a step of the application layer may choose its own default:
:func:`as_progress`). A count of work done out of a total is drawn as a bar (:meth:`Progress.bar`), taken by a
function as ``bar``, a callable ``(done, total)`` (:data:`Bar`); a count of unknown length (solver iterations) as
a counter (:meth:`Progress.counter`), taken as ``counter`` (:data:`Count`).

On a terminal a bar redraws itself in place; into a file, a pipe or a function it gives a line at
each quarter, so a log stays readable. Nothing goes to standard output, which ``--json`` keeps for
its one JSON object.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TextIO, TypeAlias

from piezopreload.core.errors import InputError

__all__ = ["Progress", "ProgressLike", "Bar", "Count", "as_progress", "say_of", "bar_of"]


class Progress:
    """Stage headers, indented messages and bars on ``stream`` (standard error by default), or each line given to
    ``lines`` (a function such as ``print``); ``quiet`` gives nothing."""

    def __init__(self, stream: TextIO | None = None, quiet: bool = False, width: int = 30,
                 lines: Callable[[str], None] | None = None) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.quiet = quiet
        self.width = width
        self.lines = lines
        self.tty = lines is None and bool(getattr(self.stream, "isatty", lambda: False)())
        self._open = False  # a bar or counter line redrawn in place, not yet ended

    def write(self, text: str) -> None:
        """Write ``text``; a line starting with a carriage return redraws the open line in place,
        any other first ends the open line. With ``lines``, each complete line is given to it."""
        if self.quiet:
            return
        if self.lines is not None:
            for line in text.strip("\r\n").split("\n"):
                self.lines(line)
            return
        if self._open and not text.startswith("\r"):
            text = "\n" + text
        self._open = text.startswith("\r") and not text.endswith("\n")
        self.stream.write(text)
        self.stream.flush()

    def stage(self, index: int, total: int, name: str, what: str) -> None:
        self.write(f"[{index}/{total}] {name}: {what}\n")

    def say(self, message: str) -> None:
        self.write(f"      {message}\n")

    def bar(self, label: str) -> Callable[[int, int], None]:
        """A callback ``(done, total)`` drawing a bar for ``label``; it ends its line at ``done == total``."""
        t0 = time.perf_counter()
        shown = {"quarter": -1}

        def update(done: int, total: int) -> None:
            total = max(int(total), 1)
            done = min(max(int(done), 0), total)
            elapsed = time.perf_counter() - t0
            if self.tty:
                filled = round(self.width * done / total)
                line = f"\r      {label} [{'#' * filled}{'.' * (self.width - filled)}] {done}/{total} {elapsed:5.1f} s"
                self.write(line + ("\n" if done == total else ""))
                return
            quarter = 4 * done // total
            if quarter > shown["quarter"]:
                shown["quarter"] = quarter
                self.write(f"      {label}: {done}/{total} ({elapsed:.1f} s)\n")

        return update

    def counter(self, label: str, every: int = 25) -> Callable[[int], None]:
        """A callback ``(count)`` for work of unknown length (solver iterations): on a terminal the
        count and the time so far redraw in place, elsewhere a line every ``every`` counts.
        The next message ends its line."""
        t0 = time.perf_counter()

        def update(count: int) -> None:
            elapsed = time.perf_counter() - t0
            if self.tty:
                self.write(f"\r      {label}: {count} ({elapsed:.1f} s)")
            elif count % every == 0:
                self.write(f"      {label}: {count} ({elapsed:.1f} s)\n")

        return update


#: what every step that reports progress takes: a function given each line of progress, or a :class:`Progress`
ProgressLike: TypeAlias = Callable[[str], None] | Progress
#: a bar's callback: given ``(done, total)`` as the work is done (:meth:`Progress.bar`)
Bar: TypeAlias = Callable[[int, int], None]
#: a counter's callback: given the count so far, of work of unknown length (:meth:`Progress.counter`)
Count: TypeAlias = Callable[[int], None]


def as_progress(progress: ProgressLike | None) -> Progress:
    """``progress`` as a :class:`Progress`: itself, one that gives each line to the function, or (None) one on
    standard error."""
    if isinstance(progress, Progress):
        return progress
    if progress is None:
        return Progress()
    if not callable(progress):
        raise InputError(f"progress must be a function taking a line (such as print) or a Progress, got {progress!r}")
    return Progress(lines=progress)


def say_of(progress: ProgressLike | None) -> Callable[[str], None] | None:
    """Where a step's messages go: a :class:`Progress`'s :meth:`~Progress.say`, the function itself, or None."""
    if isinstance(progress, Progress):
        return progress.say
    if progress is not None and not callable(progress):
        raise InputError(f"progress must be a function taking a line (such as print) or a Progress, got {progress!r}")
    return progress


def bar_of(progress: ProgressLike | None, label: str) -> Bar | None:
    """A bar for ``label`` drawn by ``progress`` (a function is given a line at each quarter); None for None."""
    return None if progress is None else as_progress(progress).bar(label)
