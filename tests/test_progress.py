"""Progress bars: shown on a terminal only, honest time-left estimates."""

import io

import pytest

from drake_cfvol.io.progress import Progress, eta_errors


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_no_bar_when_not_a_terminal():
    """A stream that is not a terminal (a pipe, a file) gets nothing."""
    out = io.StringIO()
    with Progress(10, "Work", file=out, delay=0, mininterval=0) as bar:
        for _ in range(10):
            bar.update(1)
    assert out.getvalue() == "" and not bar.shown


def test_bar_on_a_terminal_shows_time_left():
    """On a terminal the bar names the work, its units and the time left."""
    out = _Terminal()
    with Progress(4, "Certifying", file=out, unit="window", delay=0, mininterval=0) as bar:
        for _ in range(4):
            bar.update(1)
    text = out.getvalue()
    assert "Certifying" in text and "window" in text and "left" in text


def test_disabled_bar_is_silent_on_a_terminal():
    """enabled=False (the CLI's --json) draws nothing, even on a terminal."""
    out = _Terminal()
    with Progress(3, "Work", file=out, enabled=False, delay=0, mininterval=0) as bar:
        bar.update(3)
    assert out.getvalue() == ""


def test_no_time_left_where_work_may_restart():
    """eta=False (certification's run of free samples restarts after a cut)
    shows no time-left estimate."""
    out = _Terminal()
    with Progress(100, "Certifying", file=out, eta=False, delay=0, mininterval=0) as bar:
        bar.set(60, cuts=2)
        bar.set(0, cuts=3)
    text = out.getvalue()
    assert "Certifying" in text and "left" not in text and "cuts=3" in text


def test_history_counts_units_and_totals():
    """history holds (seconds, units done, total) after each update, set()
    moves backwards too, and set_total re-estimates."""
    bar = Progress(10, "Work", enabled=False)
    bar.update(4)
    bar.set(2)
    bar.set_total(20)
    bar.update(1)
    assert [(n, total) for _, n, total in bar.history] == [(4, 10), (2, 10), (3, 20)]


def test_eta_error_zero_for_uniform_work():
    """Work done at a constant rate: the estimate (elapsed x left / done) is
    exact at every fraction."""
    hist = [(t, 2.0 * t, 20.0) for t in [0.5 * i for i in range(1, 21)]]  # 2 units/s, 10 s
    errs = eta_errors(hist)
    assert set(errs) == {0.25, 0.5, 0.75} and max(errs.values()) == pytest.approx(0.0, abs=1e-12)


def test_eta_error_by_hand():
    """Half the units in the first 2 s, the rest in 6 s: at 4 s (50 % of
    8 s) the last update (t = 2, n = 5 of 10) gives a time left of
    4 x 5 / 5 = 4 s; the truth is 4 s. At 2 s (25 %): 2 x 5 / 5 = 2 s left
    against 6 s, an error of 2/3."""
    hist = [(1.0, 2.5, 10.0), (2.0, 5.0, 10.0), (8.0, 10.0, 10.0)]
    errs = eta_errors(hist, at=(0.25, 0.5))
    assert errs[0.25] == pytest.approx(2 / 3) and errs[0.5] == pytest.approx(0.0)


def test_library_is_quiet_by_default(capfd):
    """Library calls draw no bar unless asked (progress=False default)."""
    import drake_cfvol as cf
    from drake_cfvol.algorithm.metrics import confidence_factor

    wc = cf.load_workcell("automotive")
    path = cf.plan_nominal_path(wc, *wc.configuration("path1"), seed=0)
    table = cf.estimate_bounds(wc, path, resolution=100)
    capfd.readouterr()
    confidence_factor(wc, table, windows=2, samples=50, seed=0)
    assert capfd.readouterr().err == ""


def test_timed_bar_counts_seconds_up_to_the_expected_cost():
    """A call that cannot report progress (one step): the bar advances with
    elapsed time, never past 99 % of the expected cost before the call
    returns, and ends complete."""
    import time

    from drake_cfvol.io.progress import timed_steps

    out = _Terminal()
    with timed_steps({"all": 10.0}, "Compiling", file=out, tick_s=0.02, delay=0) as step:
        time.sleep(0.2)
    ticks = [n for _, n, _ in step.bar.history]
    assert len(ticks) >= 3 and all(n <= 9.9 for n in ticks[:-1]) and ticks[-1] == 10.0
    assert 0.1 <= ticks[-2] <= 1.0  # elapsed seconds, not work units
    assert "Compiling" in out.getvalue()


def test_timed_steps_time_left_follows_the_measured_rate(monkeypatch):
    """Steps whose shares are in the ratio of their durations, on a machine
    three times slower than the shares say: the time left shown at 25, 50
    and 75 % of the run is within 30 % of the truth (the rate is measured
    after the first step and applied within the next). On a clock of the
    test's own, ticked as the bar's thread ticks, so the machine's load
    cannot change the answer."""
    from drake_cfvol.io import progress

    now = [0.0]
    monkeypatch.setattr(progress.time, "perf_counter", lambda: now[0])
    shares = {"a": 0.04, "b": 0.12, "c": 0.04}  # seconds on the "reference machine"
    with progress.timed_steps(shares, "Steps", file=_Terminal(), tick_s=3600.0, delay=0) as step:
        for name, s in shares.items():
            for _ in range(50):  # the bar's thread's ticks within the step
                now[0] += 3 * s / 50
                step.tick()
            step(name)
    errors = progress.eta_errors(step.bar.history)
    assert errors.get(0.5, 1.0) < 0.3 and errors.get(0.75, 1.0) < 0.3, errors
