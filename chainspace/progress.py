"""Progress of a long stage: a rich bar on a terminal, plain lines when the output is piped (a log, CI).

Every stage that walks over frames (tracking, rendering, drawing an overlay) reports through
:func:`progress_reporter`, so they all look alike and a caller can take the counts instead.

Work that is not a walk over frames (the robot fit's stages: its candidates, starts and choices, each a
solve over the whole sequence) logs its stages to the ``chainspace.stages`` logger at INFO level
(:func:`stage`, :func:`stage_steps`): silent unless logging is configured; the command line prints them
as plain lines with the elapsed time (:func:`print_stages`), a Python user sees them with
``logging.basicConfig(level=logging.INFO)``.
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

__all__ = ["progress_reporter", "stage", "stage_steps", "print_stages", "STAGES"]

STAGES = logging.getLogger("chainspace.stages")


def stage(message: str, *args: object) -> None:
    """Log the start of a stage (``message % args``) to :data:`STAGES`."""
    STAGES.info(message, *args)


def stage_steps(label: str, total: int, every_s: float = 2.0) -> Callable[[int], None]:
    """``step(done)`` logs the start of step ``done + 1`` of ``total`` of a stage, with the time left
    estimated from the steps done so far (their mean time): the first step, then one at most every
    ``every_s`` seconds (quick steps would flood a log)."""
    t0 = time.perf_counter()
    last = [-float("inf")]

    def step(done: int) -> None:
        now = time.perf_counter()
        if not STAGES.isEnabledFor(logging.INFO) or now - last[0] < every_s:
            return
        last[0] = now
        left = f", about {(now - t0) / done * (total - done):.0f} s left in this stage" if done else ""
        STAGES.info("%s %d/%d%s", label, done + 1, total, left)

    return step


@contextmanager
def print_stages(prefix: str = "", say: Callable[[str], None] | None = None) -> Iterator[None]:
    """Print the stages logged inside the block to stderr as plain lines, each with the seconds since the
    block began (readable on a terminal and in a log alike); ``say(line)`` instead of printing, if given."""
    t0 = time.perf_counter()

    class _Lines(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            line = f"{prefix}[{time.perf_counter() - t0:6.1f} s] {record.getMessage()}"
            if say is None:
                print(line, file=sys.stderr, flush=True)
            else:
                say(line)

    handler = _Lines(logging.INFO)
    level, propagate = STAGES.level, STAGES.propagate
    STAGES.addHandler(handler)
    STAGES.setLevel(logging.INFO)
    STAGES.propagate = False  # not twice where the root logger prints too
    try:
        yield
    finally:
        STAGES.removeHandler(handler)
        STAGES.setLevel(level)
        STAGES.propagate = propagate


def time_left(elapsed: float, done: int, total: int) -> str:
    """``"12 s elapsed, about 40 s left"`` for ``done`` of ``total`` steps in ``elapsed`` seconds (the
    rate so far; no estimate before the first step)."""
    text = f"{elapsed:.0f} s elapsed"
    if 0 < done < total:
        text += f", about {elapsed * (total - done) / done:.0f} s left"
    return text


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
    t0 = time.perf_counter()

    def plain(done: int) -> None:
        if done - last[0] >= step or (done == total and last[0] != total):
            last[0] = done
            print(f"{label}: {done}/{total} {unit}, {time_left(time.perf_counter() - t0, done, total)}",
                  file=sys.stderr, flush=True)

    yield plain
