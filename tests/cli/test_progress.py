"""Progress in a log: plain lines at an interval when stderr is not a terminal (rjfit fit, render, validate)."""
import io
import os
import re
import subprocess
import sys

import pytest

from rjfit.progress import INTERVAL_ENV, LineProgress, TerminalProgress, line_interval, progress, tracked

DURATION = r"(\d+ s|\d+\.\d min)"
CHAIN_LINE = re.compile(rf"^chain (\d): iteration (\d+) of (\d+), model \(n_u, n_v\) = \((\d), (\d)\), {DURATION}, "
                        rf"(about {DURATION} left|done)$")


class Clock:
    """A clock the test advances: seconds since the start."""

    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def test_lines_come_at_the_interval_and_at_the_end():
    stream, clock = io.StringIO(), Clock()
    bar = LineProgress(100, "chain 1", "iteration", interval=10.0, stream=stream, clock=clock)
    for _ in range(25):       # 4 s per iteration: a line every 12 s (the first 10 s or more after the last)
        clock.now += 4.0
        bar.update(1, lambda: "model (n_u, n_v) = (1, 2)")
    bar.close()
    lines = stream.getvalue().splitlines()
    assert lines[0] == "chain 1: iteration 3 of 100, model (n_u, n_v) = (1, 2), 12 s, about 6.5 min left"
    counts = [int(re.search(r"iteration (\d+)", line).group(1)) for line in lines]
    assert counts == [3, 6, 9, 12, 15, 18, 21, 24, 25]       # then the last count, written by close()
    assert lines[-1] == "chain 1: iteration 25 of 100, model (n_u, n_v) = (1, 2), 100 s, about 5.0 min left"


def test_a_resumed_count_estimates_from_this_run_s_pace_and_says_done():
    stream, clock = io.StringIO(), Clock()
    bar = LineProgress(10, "chain 0", "iteration", initial=6, interval=0.0, stream=stream, clock=clock)
    clock.now = 2.0
    bar.update(2)                           # 2 iterations in 2 s: 2 left take 2 s
    clock.now = 4.0
    bar.update(2)
    bar.close()                             # nothing new to say
    assert stream.getvalue().splitlines() == ["chain 0: iteration 8 of 10, 2 s, about 2 s left",
                                             "chain 0: iteration 10 of 10, 4 s, done"]


def test_progress_is_a_bar_only_on_a_terminal(monkeypatch):
    class Terminal(io.StringIO):
        def isatty(self):
            return True

    assert isinstance(progress(5, "x", stream=io.StringIO()), LineProgress)
    bar = progress(5, "x", stream=Terminal())
    assert isinstance(bar, TerminalProgress)
    bar.close()
    monkeypatch.setenv(INTERVAL_ENV, "2.5")
    assert line_interval() == 2.5
    monkeypatch.setenv(INTERVAL_ENV, "soon")
    with pytest.raises(ValueError, match=INTERVAL_ENV):
        line_interval()


def test_tracked_loops_write_their_last_line_to_a_log(capsys):
    assert list(tracked(range(4), "validate", "light")) == [0, 1, 2, 3]
    assert capsys.readouterr().err.splitlines()[-1].startswith("validate: light 4 of 4, ")


def test_a_redirected_fit_writes_progress_lines_per_chain(paper_sphere_small, tmp_path):
    """`rjfit fit` with stderr captured (a pipe, not a terminal): per chain, lines with the
    iteration, the model, the seconds and the time left; here one per iteration
    (RJFIT_PROGRESS_SECONDS=0). About 10 s: two chains of 30 iterations at 48 x 48."""
    environment = {**os.environ, INTERVAL_ENV: "0"}
    result = subprocess.run([sys.executable, "-m", "rjfit", "fit", str(paper_sphere_small), "--out",
                             str(tmp_path / "fit"), "--chains", "2", "--iterations", "30", "--allow-unvalidated"],
                            capture_output=True, text=True, env=environment, check=False)
    assert result.returncode == 0, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.startswith("chain ")]
    assert all(CHAIN_LINE.match(line) for line in lines), [line for line in lines if not CHAIN_LINE.match(line)]
    for chain in (0, 1):
        counts = [int(m.group(2)) for m in map(CHAIN_LINE.match, lines) if m.group(1) == str(chain)]
        assert counts == list(range(1, 31)), (chain, counts)
    assert "\r" not in result.stderr and "it/s" not in result.stderr       # no progress bar in a log
