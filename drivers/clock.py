"""Clocks: the host's monotonic clock for a real cell, simulated time for a simulated one.

Every timestamp a driver takes (a state frame's arrival, a pulser reading's answer) and every
wait it makes on streamed state goes through a ``Clock``. On a real cell that is
``HOST_CLOCK`` (``time.monotonic``) and nothing else changes. A simulated cell served in the
same process as its client (``ucal calibrate --sim``) runs on a ``SimClock`` instead, so that a
run goes as fast as it computes and gives the same readings whatever the machine's load:

* Simulated time ``t`` advances only when something models time passing: a pulser
  acquisition (the simulator charges its transport latency and acquisition time), or a client
  that waits for the state stream (``Clock.wait``: the client is idle, so time jumps to the
  next state frame).
* The controller simulator registers its state stream as a *ticker*: at every period boundary
  that ``t`` crosses it sends one state frame per client, and ``advance_to`` does not go past
  that instant until the client's reader has taken the frame (``frames_taken``). So every
  frame is stamped with the simulated instant it describes, every reading with the instants
  of its request and answer, and the order of all of them is fixed by the run itself, not by
  how the host schedules threads.

The wire protocols and the driver code are those of a real cell; only the clock object
differs. Lock-step needs the client in the same process; a simulated cell served to another
process (``ucal sim serve``) runs on the host clock, scaled.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

log = logging.getLogger(__name__)


class Clock(Protocol):
    """Time as the drivers see it (seconds, monotonic)."""

    def now(self) -> float:
        """Current time (s)."""
        ...

    def wait(self, cond: threading.Condition, timeout_s: float) -> None:
        """Wait on ``cond`` (held by the caller) for a notification or ``timeout_s``."""
        ...

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` pass."""
        ...

    def frames_taken(self, count: int) -> None:
        """Tell the clock that a client's reader has taken ``count`` state frames."""
        ...


class HostClock:
    """The host's monotonic clock: what a real cell runs on."""

    def now(self) -> float:
        return time.monotonic()

    def wait(self, cond: threading.Condition, timeout_s: float) -> None:
        cond.wait(timeout_s)

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)

    def frames_taken(self, count: int) -> None:
        """Nothing to do: real state frames are not handed over in lock step."""


#: The clock of every real cell.
HOST_CLOCK = HostClock()


@dataclass
class _Ticker:
    period_s: float
    fire: Callable[[float], int]  # send the frames of instant t; returns how many were sent
    ready: Callable[[], bool]  # whether anybody listens (a client is connected)
    next_k: int = 1

    @property
    def next_t(self) -> float:
        return self.next_k * self.period_s


class SimClock:
    """Simulated time of an in-process simulated cell, advanced in lock step with its client.

    ``handoff_timeout_s`` (real seconds) bounds the wait for a client's reader to take a state
    frame; past it the frame is taken as lost (the client has gone) and time goes on.
    """

    #: Real time to let pass while nobody listens to the state stream yet (s).
    IDLE_POLL_S = 0.001

    def __init__(self, handoff_timeout_s: float = 30.0):
        self._t = 0.0
        self._advancing = threading.RLock()  # one advance at a time
        self._handoff = threading.Condition()  # guards _pending
        self._pending = 0  # frames sent and not yet taken
        self._tickers: list[_Ticker] = []
        self._closed = False
        self.handoff_timeout_s = float(handoff_timeout_s)

    def now(self) -> float:
        return self._t

    def add_ticker(
        self, period_s: float, fire: Callable[[float], int], ready: Callable[[], bool]
    ) -> None:
        """Call ``fire(t)`` at every multiple ``t`` of ``period_s`` that time reaches."""
        if not (period_s > 0 and math.isfinite(period_s)):
            raise ValueError(f"period_s must be positive, got {period_s}")
        with self._advancing:
            k = math.floor(self._t / period_s) + 1
            self._tickers.append(_Ticker(float(period_s), fire, ready, k))

    def remove_ticker(self, fire: Callable[[float], int]) -> None:
        """Stop calling ``fire``."""
        with self._advancing:
            self._tickers = [t for t in self._tickers if t.fire != fire]

    def close(self) -> None:
        """End lock step (the client has gone): hand-overs stop waiting, waits stop advancing."""
        with self._handoff:
            self._closed = True
            self._handoff.notify_all()

    def _listening(self) -> bool:
        return not self._closed and any(t.ready() for t in self._tickers)

    def _next_tick_s(self) -> float:
        return min((t.next_t for t in self._tickers), default=math.inf)

    def advance_to(self, t_s: float) -> None:
        """Let time run to ``t_s``, firing every tick on the way and handing its frames over."""
        with self._advancing:
            while True:
                due = [t for t in self._tickers if t.next_t <= t_s]
                if not due:
                    break
                tick_t = min(t.next_t for t in due)
                self._t = max(self._t, tick_t)
                for ticker in due:
                    if ticker.next_t == tick_t:
                        ticker.next_k += 1
                        self._hand_over(ticker.fire(tick_t))
            self._t = max(self._t, float(t_s))

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            self.advance_to(self._t + seconds)

    def wait(self, cond: threading.Condition, timeout_s: float) -> None:
        """Idle until the next state frame (or ``timeout_s``), with ``cond`` released meanwhile."""
        if not self._listening():
            # The client's state connection is still being accepted: nothing may happen in
            # simulated time until it is, or the run's start would depend on the scheduler.
            cond.wait(self.IDLE_POLL_S)
            return
        target = min(self._next_tick_s(), self._t + max(timeout_s, 0.0))
        cond.release()
        try:
            self.advance_to(target)
        finally:
            cond.acquire()

    def frames_taken(self, count: int) -> None:
        with self._handoff:
            self._pending -= count
            self._handoff.notify_all()

    def _hand_over(self, sent: int) -> None:
        """Wait (real time, bounded) until the client's reader has taken ``sent`` frames."""
        if sent <= 0:
            return
        deadline = time.monotonic() + self.handoff_timeout_s
        with self._handoff:
            self._pending += sent
            while self._pending > 0:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or not self._listening():
                    log.warning(
                        "simulated clock: %d state frame(s) not taken at t=%.3f s; going on",
                        self._pending,
                        self._t,
                    )
                    self._pending = 0
                    break
                self._handoff.wait(min(remaining, 0.05))
