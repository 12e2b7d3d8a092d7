"""Progress of long steps: a bar on a terminal, plain lines in a log.

A progress bar redraws one line with carriage returns: on a terminal that is what a reader
wants, in a file (``rjfit fit ... > log 2>&1``) it is noise or, as tqdm does when it is not
writing to a terminal, nothing at all. :func:`progress` gives a tqdm bar when the stream is
a terminal and a :class:`LineProgress` otherwise, which writes one plain line at most every
:func:`line_interval` seconds (and one at the end): what was done, of how many, the
caller's detail (a chain's current model), seconds so far and an estimate of the seconds
left. Both have the same three methods (``update``, ``write``, ``close``).
"""
from __future__ import annotations

import contextlib
import math
import os
import sys
import time

__all__ = ["progress", "tracked", "phase", "LineProgress", "TerminalProgress", "line_interval", "INTERVAL_ENV",
           "DEFAULT_INTERVAL"]

#: environment variable that sets the seconds between two progress lines in a log
INTERVAL_ENV = "RJFIT_PROGRESS_SECONDS"
#: seconds between two progress lines in a log: a fit of a few minutes writes a dozen lines per chain
DEFAULT_INTERVAL = 10.0


def line_interval() -> float:
    """Seconds between two progress lines: ``$RJFIT_PROGRESS_SECONDS``, else :data:`DEFAULT_INTERVAL`.

    Raises
    ------
    ValueError
        If the variable is set to something other than a non-negative number.
    """
    text = os.environ.get(INTERVAL_ENV)
    if text is None or not text.strip():
        return DEFAULT_INTERVAL
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(f"{INTERVAL_ENV}={text!r} is not a number of seconds >= 0")
    return value


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.1f} min"


def _detail_text(detail) -> str:
    return str(detail() if callable(detail) else detail)


class LineProgress:
    """Progress as plain lines: ``desc: unit n of total, detail, 12 s, about 40 s left``.

    A line is written when at least ``interval`` seconds have passed since the last one, and
    by :meth:`close` for the last count if it was not written yet. The estimate of the time
    left extrapolates this run's own pace (a resumed chain's earlier iterations are not
    counted as done in this run's seconds).

    Parameters
    ----------
    total : int
    desc : str
        What progresses (``chain 0``).
    unit : str
        What is counted (``iteration``).
    initial : int
        Count already done before this run (a resumed chain).
    interval : float, optional
        Seconds between two lines (default :func:`line_interval`).
    stream : file, optional
        Where lines go (default ``sys.stderr``).
    clock : callable, optional
        Seconds now (default ``time.perf_counter``).
    """

    def __init__(self, total: int, desc: str, unit: str = "step", *, initial: int = 0, interval: float | None = None,
                 stream=None, clock=time.perf_counter):
        self.total, self.desc, self.unit = int(total), desc, unit
        self.n = self.start = int(initial)
        self.interval = line_interval() if interval is None else float(interval)
        self.stream = sys.stderr if stream is None else stream
        self.clock = clock
        self.started = self.last_line = clock()
        self.written = None        # the count of the last line written
        self.detail = ""

    def update(self, n: int = 1, detail=None) -> None:
        """Count ``n`` more; ``detail`` (text, or a callable giving it, called only for a line) goes into the line."""
        self.n += n
        if detail is not None:
            self.detail = detail
        now = self.clock()
        if now - self.last_line >= self.interval:
            self._line(now)

    def write(self, text: str, say=None) -> None:
        """A line of the caller's own (what a step found) between progress lines: ``say(text)``, or to the stream."""
        if say is None:
            print(text, file=self.stream, flush=True)
        else:
            say(text)

    def close(self) -> None:
        """Write the last count's line, unless it was the last line written."""
        if self.written != self.n:
            self._line(self.clock())

    def text(self, now: float) -> str:
        """The progress line at time ``now``."""
        elapsed = now - self.started
        parts = [f"{self.desc}: {self.unit} {self.n} of {self.total}"]
        detail = _detail_text(self.detail)
        if detail:
            parts.append(detail)
        parts.append(_duration(elapsed))
        done_here = self.n - self.start
        if self.n >= self.total:
            parts.append("done")
        elif done_here > 0:
            parts.append(f"about {_duration(elapsed / done_here * (self.total - self.n))} left")
        return ", ".join(parts)

    def _line(self, now: float) -> None:
        # one write per line, newline included: chains in other processes write to the same
        # log, and print() writes the text and its newline apart (their lines would interleave)
        self.stream.write(self.text(now) + "\n")
        self.stream.flush()
        self.last_line, self.written = now, self.n


class TerminalProgress:
    """A tqdm bar with :class:`LineProgress`'s methods (the detail shown after the bar)."""

    def __init__(self, total: int, desc: str, unit: str = "step", *, initial: int = 0, position=None,
                 leave: bool = True, stream=None):
        from tqdm import tqdm

        self.bar = tqdm(total=total, initial=initial, desc=desc, unit=unit, position=position, leave=leave,
                        mininterval=1.0, file=sys.stderr if stream is None else stream)

    def update(self, n: int = 1, detail=None) -> None:
        if detail is not None:
            self.bar.set_postfix_str(_detail_text(detail), refresh=False)
        self.bar.update(n)

    def write(self, text: str, say=None) -> None:
        """A line above the bar (the bar is redrawn below it): ``say(text)``, or printed to the bar's stream."""
        self.bar.clear()
        if say is None:
            print(text, file=self.bar.fp, flush=True)
        else:
            say(text)
        self.bar.refresh()

    def close(self) -> None:
        self.bar.close()


def progress(total: int, desc: str, unit: str = "step", *, initial: int = 0, position=None, leave: bool = True,
             stream=None):
    """A :class:`TerminalProgress` bar if ``stream`` (default ``sys.stderr``) is a terminal, else :class:`LineProgress`.

    ``position`` and ``leave`` only concern the bar (several chains' bars, one line each).
    """
    stream = sys.stderr if stream is None else stream
    if _is_terminal(stream):
        return TerminalProgress(total, desc, unit, initial=initial, position=position, leave=leave, stream=stream)
    return LineProgress(total, desc, unit, initial=initial, stream=stream)


def _is_terminal(stream) -> bool:
    isatty = getattr(stream, "isatty", None)
    try:
        return bool(isatty()) if isatty is not None else False
    except ValueError:          # a closed stream
        return False


@contextlib.contextmanager
def phase(desc: str, enabled: bool = True, stream=None, clock=time.perf_counter):
    """Announce a step that can take long: ``desc ...`` when it starts, ``desc: done in 12 s`` when it ends.

    Plain lines (one write each, like :class:`LineProgress`'s), on a terminal as in a log: a
    step without a count of its own (a maximisation, a few array passes) is followed by when
    it began and how long it took; a step with a count adds a :func:`tracked` loop inside.
    Nothing is written when ``enabled`` is false (tests, the precompile run, Dask workers),
    and nothing about the step changes either way.
    """
    stream = sys.stderr if stream is None else stream
    if not enabled:
        yield
        return
    started = clock()
    stream.write(f"{desc} ...\n")
    stream.flush()
    yield
    stream.write(f"{desc}: done in {_duration(clock() - started)}\n")
    stream.flush()


def tracked(items, desc: str, unit: str = "step", enabled: bool = True):
    """Yield ``items`` (a sized sequence) with :func:`progress` counting them; closed when the loop ends or stops.

    With ``enabled`` false the items are yielded as they are, without a bar or a line.
    """
    if not enabled:
        yield from items
        return
    bar = progress(len(items), desc, unit)
    try:
        for item in items:
            yield item
            bar.update(1)
    finally:
        bar.close()
