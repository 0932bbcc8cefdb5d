"""Progress of a long stage: a rich bar on a terminal, plain lines when the output is piped (a log, CI).

Every stage that walks over frames (tracking, rendering, drawing an overlay) reports through
:func:`progress_reporter`, so they all look alike and a caller can take the counts instead.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager

__all__ = ["progress_reporter"]


@contextmanager
def progress_reporter(progress: bool | Callable[[int, int], None], total: int, label: str, *,
                      unit: str = "frames") -> Iterator[Callable[[int], None]]:
    """Yield ``report(done)`` for a stage of ``total`` steps.

    ``progress`` is False (silent), True (a rich bar with the time left on a terminal; on a pipe a plain
    line ``label: done/total unit`` every tenth of the way, because a redrawn bar is unreadable in a log),
    or the caller's own function ``progress(done, total)``.
    """
    if callable(progress):
        yield lambda done: progress(done, total)
        return
    if not progress:
        yield lambda done: None
        return
    if sys.stderr.isatty():
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeRemainingColumn,
        )

        columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
        with Progress(*columns, console=Console(stderr=True, highlight=False), transient=True) as bar:
            task = bar.add_task(label, total=total)
            yield lambda done: bar.update(task, completed=done)
        return
    step = max(1, total // 10)
    last = [0]

    def plain(done: int) -> None:
        if done - last[0] >= step or (done == total and last[0] != total):
            last[0] = done
            print(f"{label}: {done}/{total} {unit}", file=sys.stderr, flush=True)

    yield plain
