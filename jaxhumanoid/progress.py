"""Progress of long runs: ``Progress`` for runs of many steps (Table II, figure scripts, sweeps), one
line per step; ``IterationLine`` for one solve, one updating line per solver stage.

    progress = Progress(len(cells), quiet=args.quiet)
    for task, scheme in progress.iter(cells, label=lambda c: f"{c[0]} {c[1]}"):
        ...                                   # one step
        progress.note("Solve_Succeeded, iterations [325, 355]")

prints lines such as

    [ 3/16] T1 A,F+C,2S  start  elapsed 1m 12s  ETA 6m 24s
    [ 3/16] T1 A,F+C,2S  done in 41.0 s  Solve_Succeeded, iterations [325, 355]

The ETA is the mean duration of the finished steps times the number of steps left; it is not
shown before the first step has finished. Steps that run concurrently and finish in any order
(a pool of workers) are reported by ``completed(label, message)``, one line each, with the ETA
from the rate so far (elapsed / done x left). Standard library only; output goes to ``stream``
(default ``sys.stdout``) and is flushed after every line; ``quiet=True`` prints nothing.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterable, Iterator
from typing import TextIO, TypeVar

T = TypeVar("T")


def format_duration(seconds: float) -> str:
    """``"42.0 s"``, ``"3m 05s"`` or ``"1h 02m"``; ``"?"`` for a negative or non-finite value."""
    if seconds != seconds or seconds < 0 or seconds == float("inf"):
        return "?"
    if seconds < 60:
        return f"{seconds:.1f} s"
    minutes, secs = divmod(int(round(seconds)), 60)
    if minutes < 60:
        return f"{minutes}m {secs:02d}s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours}h {minutes:02d}m"


class Progress:
    """Reports step ``i`` of ``total``: its label, the elapsed time and an ETA, one line per event.

    total: number of steps (>= 0); quiet: print nothing; stream: where lines go (default stdout);
    clock: a monotonic clock in seconds (``time.perf_counter``; replaceable for tests).
    """

    def __init__(
        self,
        total: int,
        quiet: bool = False,
        stream: TextIO | None = None,
        clock: Callable[[], float] = time.perf_counter,
    ):
        if not isinstance(total, int) or isinstance(total, bool) or total < 0:
            raise ValueError(f"total: expected a non-negative integer number of steps, got {total!r}")
        self.total = total
        self.quiet = bool(quiet)
        self.stream = stream
        self.clock = clock
        self.t_start = clock()
        self.done = 0
        self.durations: list[float] = []
        self._current: tuple[int, str, float] | None = None  # (index, label, start time)
        self._notes: list[str] = []
        self.lines: list[str] = []  # every line, also when quiet (handy for logs and tests)

    # -- timing -----------------------------------------------------------------------------
    @property
    def elapsed(self) -> float:
        return self.clock() - self.t_start

    @property
    def eta(self) -> float | None:
        """Seconds left (mean finished-step duration x steps left); None before a step has finished."""
        if not self.durations:
            return None
        left = max(self.total - self.done, 0)
        return sum(self.durations) / len(self.durations) * left

    def _prefix(self, index: int, label: str) -> str:
        width = len(str(self.total))
        return f"[{index:>{width}}/{self.total}] {label}".rstrip()

    def _emit(self, line: str) -> None:
        self.lines.append(line)
        if not self.quiet:
            stream = self.stream if self.stream is not None else sys.stdout
            print(line, file=stream, flush=True)

    # -- events -----------------------------------------------------------------------------
    def start(self, label: str = "") -> None:
        """Begin the next step (closes a step still open)."""
        if self._current is not None:
            self.finish()
        index = self.done + 1
        self._current = (index, str(label), self.clock())
        eta = self.eta
        eta_text = "" if eta is None else f"  ETA {format_duration(eta)}"
        self._emit(f"{self._prefix(index, str(label))}  start  elapsed {format_duration(self.elapsed)}{eta_text}")

    def note(self, message: str) -> None:
        """Attach a message to the current step; it is printed with the step's ``done`` line."""
        if self._current is None:
            self._emit(f"  {message}")
        else:
            self._notes.append(str(message))

    def finish(self, message: str = "") -> float:
        """End the current step; returns its duration in seconds."""
        if self._current is None:
            raise RuntimeError("Progress.finish: no step was started")
        index, label, t0 = self._current
        duration = self.clock() - t0
        self.durations.append(duration)
        self.done += 1
        self._current = None
        text = "  ".join(s for s in (*self._notes, message) if s)
        self._notes = []
        eta = self.eta
        eta_text = f"  ETA {format_duration(eta)}" if eta is not None and self.done < self.total else ""
        self._emit(
            f"{self._prefix(index, label)}  done in {format_duration(duration)}{'  ' + text if text else ''}{eta_text}"
        )
        return duration

    def completed(self, label: str, message: str = "") -> None:
        """Count one step that ran elsewhere (a worker) and has just finished: one line with the
        elapsed time and the ETA elapsed / done x left (concurrent steps overlap, so the mean
        step duration would overstate what is left)."""
        self.done += 1
        left = max(self.total - self.done, 0)
        eta = f"  ETA {format_duration(self.elapsed / self.done * left)}" if left else ""
        text = f"  {message}" if message else ""
        self._emit(f"{self._prefix(self.done, str(label))}  done{text}  elapsed {format_duration(self.elapsed)}{eta}")

    def summary(self) -> str:
        """One closing line: steps done and total elapsed time (printed unless quiet)."""
        line = f"{self.done}/{self.total} steps in {format_duration(self.elapsed)}"
        self._emit(line)
        return line

    def iter(self, items: Iterable[T], label: Callable[[T], str] | None = None) -> Iterator[T]:
        """Yield ``items`` wrapping each in start/finish; ``label(item)`` names it (default str)."""
        for item in items:
            self.start(label(item) if label is not None else str(item))
            yield item
            if self._current is not None:
                self.finish()


class IterationLine:
    """One updating line per solver stage: ``stage 2 (dynamic)  iteration 57  objective ...
    infeasibility ...``, rewritten in place (carriage return) at most every ``interval`` seconds
    and closed with a newline when the stage changes or ``close`` is called.

    Call it as ``solve(..., progress=line)``: ``line(stage, iteration, objective, inf_pr)``.
    ``live=None`` rewrites in place only on a terminal; elsewhere (logs, pipes) each stage gets
    its final line only. ``quiet=True`` prints nothing.
    """

    def __init__(
        self,
        stream: TextIO | None = None,
        quiet: bool = False,
        live: bool | None = None,
        interval: float = 0.1,
        clock: Callable[[], float] = time.perf_counter,
    ):
        self.stream = stream if stream is not None else sys.stderr
        self.quiet = bool(quiet)
        self.live = bool(getattr(self.stream, "isatty", lambda: False)()) if live is None else bool(live)
        self.interval, self.clock = float(interval), clock
        self._stage: str | None = None
        self._text = ""
        self._shown = -float("inf")
        self._width = 0

    def __call__(self, stage: str, iteration: int, objective: float, inf_pr: float) -> None:
        if stage != self._stage:
            self.close()
            self._stage = stage
        self._text = f"{stage}  iteration {iteration:5d}  objective {objective: .6e}  infeasibility {inf_pr:.1e}"
        now = self.clock()
        if self.live and now - self._shown >= self.interval:
            self._shown = now
            self._write(self._text)

    def status(self, text: str) -> None:
        """Show ``text`` in place until the next iterate replaces it (on a terminal only): what a
        solve does before its first iteration, e.g. the set-up and compilation of a cold start."""
        if self.live:
            self._write(text)

    def _write(self, text: str) -> None:
        if self.quiet:
            return
        pad = " " * max(self._width - len(text), 0)
        self._width = len(text)
        self.stream.write(f"\r{text}{pad}")
        self.stream.flush()

    def close(self) -> None:
        """End the current stage's line (with its last iterate)."""
        if self._stage is None:
            return
        if self.live:
            self._write(self._text)
        elif not self.quiet:
            self.stream.write(self._text)
        if not self.quiet:
            self.stream.write("\n")
            self.stream.flush()
        self._stage, self._width, self._shown = None, 0, -float("inf")
