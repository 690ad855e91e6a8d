"""Progress of a long command on standard error: stage lines, messages and progress bars.

On a terminal a bar redraws itself in place; into a file or a pipe it prints a line at each
quarter, so a log stays readable. Nothing goes to standard output, which ``--json`` keeps for
its one JSON object.
"""

from __future__ import annotations

import sys
import time
from typing import Callable, TextIO

__all__ = ["Progress"]


class Progress:
    """Stage headers, indented messages and bars; ``quiet`` prints nothing."""

    def __init__(self, stream: TextIO | None = None, quiet: bool = False, width: int = 30) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.quiet = quiet
        self.width = width
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())

    def write(self, text: str) -> None:
        if not self.quiet:
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
