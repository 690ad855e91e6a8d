"""Progress of a long command: stage lines, messages and progress bars, and the one type every step takes for it.

Every step of the API that reports progress (``load_study``, ``Study.design``, ``.tune``, ``.learn``,
``.track_schedule``, ``.run``, ``.sweep``, ``Study.validate``, ...) takes ``progress`` of one type,
:data:`ProgressLike`: a function given each line (``print``, a logger's ``info``), or a :class:`Progress`
(stage lines, indented messages and bars on a stream); None is the step's default (a study's run and
sweep: a :class:`Progress` on standard error; a single step: the study's own, see ``load_study``).

The type is defined on the ground floor (:mod:`piezopreload.core.progress`), so that the design, the tuning, the
rig and the report take the same one; this module is its name at the application layer.
"""

from __future__ import annotations

from piezopreload.core.progress import Bar, Count, Progress, ProgressLike, as_progress, bar_of, say_of

__all__ = ["Progress", "ProgressLike", "Bar", "Count", "as_progress", "say_of", "bar_of"]
