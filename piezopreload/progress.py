"""Progress of a long command on standard error: stage lines, messages and progress bars.

On a terminal a bar redraws itself in place; into a file or a pipe it prints a line at each
quarter, so a log stays readable. Nothing goes to standard output, which ``--json`` keeps for
its one JSON object.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TextIO

__all__ = ["Progress"]


class Progress:
    """Stage headers, indented messages and bars; ``quiet`` prints nothing."""

    def __init__(self, stream: TextIO | None = None, quiet: bool = False, width: int = 30) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.quiet = quiet
        self.width = width
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._open = False  # a bar or counter line redrawn in place, not yet ended

    def write(self, text: str) -> None:
        """Write ``text``; a line starting with a carriage return redraws the open line in place,
        any other first ends the open line."""
        if self.quiet:
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
