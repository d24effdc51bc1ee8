"""Progress bars for long work (tqdm), shown only where a person watches.

A bar appears on stderr when it is enabled, stderr is a terminal and the
work has run for ``delay`` seconds (so steps shorter than ~2 s stay silent);
it is never written into a pipe or a file. The CLI enables bars unless
``--json`` is given; library functions take ``progress=False`` by default.

The estimated time left is tqdm's, computed from the average rate since the
start (``smoothing=0``), so a bar's units must be proportional to the work:
callers count work in units of equal cost (waypoints, samples, simulated
seconds) or weigh unequal tasks by a cost model (``benchmarks/harness.py``).
``tools/eta_check.py`` measures how far the estimates are from the truth.
"""

from __future__ import annotations

import collections
import contextlib
import sys
import threading
import time

__all__ = ["Progress", "DEFAULT_DELAY_S", "eta_errors", "finished", "timed_steps"]

#: (description, history) of the last enabled bars, newest last.
_FINISHED: collections.deque = collections.deque(maxlen=32)

#: Seconds of work before a bar appears.
DEFAULT_DELAY_S = 1.5


def _shown(x: float):
    """A count as the bar prints it: whole numbers as integers, else 0.1."""
    return int(x) if float(x).is_integer() else round(float(x), 1)


class Progress:
    """A progress bar over ``total`` units of work, or nothing.

    Use as a context manager; :meth:`update` adds done units. Whatever the
    display, it keeps ``history``, the (seconds since start, units done,
    total) after each update, from which the estimates can be checked.

    Args:
        total: units of work in all (> 0).
        desc: what is being done, shown left of the bar.
        enabled: False for no bar at all.
        unit: the unit's name (e.g. ``"waypoint"``).
        file: the stream (default stderr); no bar unless it is a terminal.
        delay: seconds before the bar appears.
        mininterval: least seconds between redraws.
        eta: False where the time left cannot be estimated honestly (work
            that may restart): the bar then shows progress and elapsed time
            only.
    """

    def __init__(
        self,
        total: float,
        desc: str,
        *,
        enabled: bool = True,
        unit: str = "it",
        file=None,
        delay: float = DEFAULT_DELAY_S,
        mininterval: float = 0.25,
        eta: bool = True,
    ):
        self.total = float(total) if total and total > 0 else 1.0
        self.n = 0.0
        self.t0 = time.perf_counter()
        self.history: list[tuple[float, float, float]] = []
        self._bar = None
        self.desc, self.enabled, self._closed = desc, enabled, False
        self._mininterval, self._last_draw, self._delay = mininterval, -float("inf"), delay
        stream = sys.stderr if file is None else file
        is_tty = bool(getattr(stream, "isatty", lambda: False)())
        if enabled and is_tty:
            from tqdm import tqdm

            left = ", {remaining} left" if eta else ""
            self._bar = tqdm(
                total=_shown(self.total),
                desc=desc,
                unit=unit,
                file=stream,
                delay=delay,
                smoothing=0.0,
                mininterval=mininterval,
                dynamic_ncols=True,
                leave=False,
                bar_format="{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} {unit} "
                "[{elapsed}" + left + "{postfix}]",
            )

    @property
    def shown(self) -> bool:
        """True if a bar is (or will be) drawn."""
        return self._bar is not None

    def update(self, n: float = 1, **postfix) -> None:
        """Adds ``n`` done units; ``postfix`` shows extra facts (e.g. cuts=3)."""
        self.set(self.n + n, **postfix)

    def set(self, n: float, **postfix) -> None:
        """Sets the done units to ``n``; it may go back (e.g. a run of
        samples that loses some to a cut)."""
        self.n = float(n)
        now = time.perf_counter()
        self.history.append((now - self.t0, self.n, self.total))
        bar = self._bar
        if bar is not None:
            if postfix:
                bar.set_postfix(postfix, refresh=False)
            bar.n = _shown(self.n)
            due = now - self._last_draw >= self._mininterval or self.n >= self.total
            if due and now - self.t0 >= self._delay:
                self._last_draw = now
                bar.refresh()
                bar.last_print_n, bar.last_print_t = bar.n, bar._time()  # so close() clears the line

    def set_total(self, total: float) -> None:
        """Changes the total (work re-estimated as it goes)."""
        self.total = max(float(total), self.n, 1e-12)
        if self._bar is not None:
            self._bar.total = _shown(self.total)

    def set_description(self, desc: str) -> None:
        """Changes what the bar says is being done."""
        if self._bar is not None:
            self._bar.set_description_str(desc, refresh=False)

    def close(self) -> None:
        if self.enabled and not self._closed:
            _FINISHED.append((self.desc, list(self.history)))
        self._closed = True
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class _StepClock:
    """What :func:`timed_steps` yields: call it with each step's name as
    the step ends."""

    def __init__(self, bar: Progress, shares: dict):
        self.bar, self.shares = bar, dict(shares)
        self.done = 0.0  # shares of the steps ended
        self.t_done = 0.0  # seconds they took
        self.t_step = 0.0  # when the current step began (since the bar's start)
        self.current = next(iter(self.shares), None)
        self._names = list(self.shares)

    def __call__(self, name: str) -> None:
        now = time.perf_counter() - self.bar.t0
        self.done += self.shares.get(name, 0.0)
        self.t_done = self.t_step = now
        i = self._names.index(name) + 1 if name in self._names else len(self._names)
        self.current = self._names[i] if i < len(self._names) else None
        self.bar.set(min(self.done, self.bar.total))

    def tick(self) -> None:
        """Within a step: advance at the rate of the steps ended so far (the
        shares' own rate, 1 share per second, before any has), never past
        99 % of the current step's share."""
        if self.current is None:
            return
        now = time.perf_counter() - self.bar.t0
        rate = self.done / self.t_done if self.t_done > 0 and self.done > 0 else 1.0
        share = self.shares[self.current]
        self.bar.set(self.done + min((now - self.t_step) * rate, 0.99 * share))


@contextlib.contextmanager
def timed_steps(
    shares: dict, desc: str, *, enabled: bool = True, file=None, tick_s: float = 0.25, delay: float = DEFAULT_DELAY_S
):
    """A bar for a sequence of calls that cannot report progress
    themselves, each with a known share of the work (seconds measured on a
    reference machine; only their ratios matter). Yields a function to call
    with each step's name as it ends. Between the ends of steps the bar
    advances at the rate measured so far, so the time left shown (the rate
    so far applied to the work left) is right on a faster or slower machine
    as long as the shares' ratios hold.
    """
    bar = Progress(sum(shares.values()), desc, enabled=enabled, unit="s", file=file, delay=delay)
    clock = _StepClock(bar, shares)
    stop = threading.Event()

    def tick():
        while not stop.wait(tick_s):
            clock.tick()

    ticker = threading.Thread(target=tick, daemon=True)
    if bar.enabled:
        ticker.start()
    try:
        yield clock
    finally:
        stop.set()
        if ticker.is_alive():
            ticker.join()
        bar.set(bar.total)
        bar.close()


def finished() -> list[tuple[str, list]]:
    """(description, history) of the last enabled bars closed in this
    process, oldest first (for ``tools/eta_check.py``)."""
    return list(_FINISHED)


def eta_errors(history: list[tuple[float, float, float]], at=(0.25, 0.5, 0.75)) -> dict:
    """How wrong the bar's time-left estimate was at fractions ``at`` of the
    run's duration. What the bar shows at time t is tqdm's estimate with
    ``smoothing=0`` from the last update before t: t x (total - done) /
    done; the truth is the time the work then still took.

    Returns:
        {fraction: |estimated - true time left| / true time left} for each
        fraction with an update before it.
    """
    if not history:
        return {}
    t_end = history[-1][0]
    out = {}
    for f in at:
        t = f * t_end
        last = [h for h in history if h[0] <= t]
        if not last or last[-1][1] <= 0 or t >= t_end:
            continue
        _, n, total = last[-1]
        left = t * (total - n) / n
        out[f] = abs(left - (t_end - t)) / (t_end - t)
    return out
