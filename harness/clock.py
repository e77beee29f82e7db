"""The runner's clock (issue 38, item 2): what the harness reads and blocks on, one seam.

Every wait of the MCP path (``harness.driver``, ``harness.liveness``, ``harness.drone_session``,
``harness.impair_link``) goes through a :class:`Clock`: the time (``monotonic``, ``time_ns``),
sleeping, a condition or an event to wait on with a timeout, a thread started.

- :data:`REAL` (:class:`RealClock`) is today's behaviour exactly: ``time.monotonic``,
  ``time.time_ns``, ``time.sleep``, ``threading.Condition`` / ``Event`` / ``Thread``.
- :class:`VirtualClock` is the simulator's (``mcp_conform.sim.runner``): a deterministic
  cooperative scheduler in the style of FoundationDB's simulation. Each thread it starts (and
  the one that calls :meth:`VirtualClock.run`) is registered; exactly one registered thread runs
  at a time, and it runs until it blocks on the clock (a sleep, a condition's or an event's
  wait, a join). The next runnable thread, first come first served, then runs; when every
  registered thread is blocked, virtual time jumps to the earliest thing due -- a wait's
  timeout, or a callback (:meth:`VirtualClock.call_at`: a datagram's delivery, a node model's
  timer) -- run in the order they fell due, ties in the order they were scheduled. Nothing
  reads a wall clock, so a run is a function of its inputs and seeds: the same seed, the same
  trace (``tests/harness/test_clock.py``).

Under the virtual clock code runs in zero virtual time; a loop that polls the clock without
blocking on it would spin forever, so every polling loop of the harness sleeps on the clock.
"""

from __future__ import annotations

import _thread
import heapq
import itertools
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

__all__ = ["REAL", "Clock", "Deadlock", "RealClock", "VirtualClock", "clock_offset_ns"]


def clock_offset_ns(tries: int = 5) -> int:
    """CLOCK_REALTIME minus CLOCK_MONOTONIC, read so that a preemption between the two reads
    cannot skew it: each try brackets one monotonic read between two wall-clock reads, and the
    tightest bracket wins. Reading the two clocks one after the other instead (as a kernel
    receive time was converted before) puts a preempted thread's whole pause into the offset,
    so a datagram could be dated before the ACK the runner had sent before it arrived (a false
    MCP-BLK-1 under load)."""
    best_width, best = None, 0
    for _ in range(tries):
        r1 = time.time_ns()
        m = time.monotonic_ns()
        r2 = time.time_ns()
        if best_width is None or r2 - r1 < best_width:
            best_width, best = r2 - r1, (r1 + r2) // 2 - m
            if best_width < 20_000:
                break
    return best


class Clock:
    """The interface (see the module docstring); :class:`RealClock` is its plain reading."""

    virtual = False

    def monotonic(self) -> float:
        raise NotImplementedError

    def time_ns(self) -> int:
        raise NotImplementedError

    def offset_ns(self) -> int:
        """``time_ns()`` minus ``monotonic()`` in ns: the run clock of a monotonic stamp."""
        raise NotImplementedError

    def sleep(self, seconds: float) -> None:
        raise NotImplementedError

    def condition(self, lock: Any = None) -> threading.Condition:
        raise NotImplementedError

    def event(self) -> threading.Event:
        raise NotImplementedError

    def start_thread(self, target: Callable[[], None], name: str) -> Any:
        """``target`` in a daemon thread of its own; the handle has ``join(timeout)``."""
        raise NotImplementedError


class RealClock(Clock):
    """The host's clocks and threads, as the harness used them before the seam."""

    def monotonic(self) -> float:
        return time.monotonic()

    def time_ns(self) -> int:
        return time.time_ns()

    def offset_ns(self) -> int:
        return clock_offset_ns()

    def sleep(self, seconds: float) -> None:
        time.sleep(seconds)

    def condition(self, lock: Any = None) -> threading.Condition:
        return threading.Condition(lock)

    def event(self) -> threading.Event:
        return threading.Event()

    def start_thread(self, target: Callable[[], None], name: str) -> Any:
        t = threading.Thread(target=target, name=name, daemon=True)
        t.start()
        return t


#: The real clock every harness object takes by default.
REAL = RealClock()


class Deadlock(RuntimeError):
    """Every registered thread is blocked with no timeout and nothing is due (or the virtual
    time limit passed): raised in the thread that called :meth:`VirtualClock.run`."""


class _Shutdown(BaseException):
    """Unwinds a registered thread still parked when its clock's run ends."""


class _VThread:
    """A registered thread. Its ``baton`` is a bare lock held while the thread may not run:
    whoever hands it the turn releases it, and the thread's own ``acquire`` takes it back (a
    binary semaphore; one release per handoff, never two). A bare lock and not a
    ``threading.Semaphore(0)``: that one is a condition and a lock in Python, which took about
    twice the CPU per handoff (5.0 against 2.6 us, a ping-pong of 20,000), and a gcs-role run
    hands the turn over some 5,000 times."""

    __slots__ = ("name", "baton", "token", "woken", "done", "ident")

    def __init__(self, name: str) -> None:
        self.name = name
        self.baton = _thread.allocate_lock()
        self.baton.acquire()  # held: the thread waits for its turn
        self.token = 0  # the block it is in (a timeout or a notify of an older one is stale)
        self.woken = False  # its last block ended by a notify, not a timeout
        self.done = False
        self.ident: int | None = None


class VirtualClock(Clock):
    """The cooperative scheduler on virtual time (see the module docstring).

    ``start``: the virtual ``monotonic()`` at the start; ``epoch_ns``: what ``time_ns()`` reads
    then; ``limit``: virtual seconds after which the run is stopped (:class:`Deadlock`); ``step``:
    virtual seconds each handoff of the baton to another thread takes (a host's context switch:
    a reply read and the send it wakes are then never stamped at one instant, as on a host)."""

    virtual = True

    def __init__(self, start: float = 1000.0, epoch_ns: int = 1_700_000_000 * 10**9,
                 limit: float = 86_400.0, step: float = 0.0) -> None:
        self.now = start
        self.step = step
        self._epoch_ns = epoch_ns - int(start * 1e9)
        self._limit = start + limit
        self._lock = threading.RLock()
        self._timers: list[tuple[float, int, Any, Any]] = []  # (t, order, thread|None, token|fn)
        self._order = itertools.count()
        self._runnable: deque[_VThread] = deque()
        self._by_ident: dict[int, _VThread] = {}
        self._root: _VThread | None = None
        self._failure: BaseException | None = None
        self._closing = False
        self._joiners: dict[int, list[tuple[_VThread, int]]] = {}
        self.switches = 0  # how many times the baton passed (a cost figure)

    # ------------------------------------------------------------------ reading
    def monotonic(self) -> float:
        return self.now

    def time_ns(self) -> int:
        return self._epoch_ns + int(round(self.now * 1e9))

    def offset_ns(self) -> int:
        return self._epoch_ns

    # ------------------------------------------------------------------ running
    def run(self, fn: Callable[[], Any]) -> Any:
        """Call ``fn`` in the calling thread, registered as the root; every thread started meanwhile
        is unwound when it returns. Raises :class:`Deadlock` when no thread can ever run again."""
        if self._root is not None:
            raise RuntimeError("VirtualClock.run: already running")
        root = self._root = _VThread(threading.current_thread().name)
        root.ident = threading.get_ident()
        self._by_ident[root.ident] = root
        self._current = root
        try:
            return fn()
        finally:
            self._shutdown()

    def _me(self) -> _VThread:
        v = self._by_ident.get(threading.get_ident())
        if v is None:
            raise RuntimeError(f"VirtualClock: thread {threading.current_thread().name!r} is not registered")
        return v

    def start_thread(self, target: Callable[[], None], name: str) -> Any:
        v = _VThread(name)

        def body() -> None:
            v.baton.acquire()
            try:
                if not self._closing:
                    target()
            except _Shutdown:
                pass
            except BaseException as exc:  # noqa: BLE001 - handed to the root, which raises it
                with self._lock:
                    if self._failure is None:
                        self._failure = exc
            finally:
                v.done = True
                self._notify_join(v)
                if not self._closing:
                    self._switch(v, leaving=True)

        th = threading.Thread(target=body, name=name, daemon=True)
        th.start()
        v.ident = th.ident
        with self._lock:
            assert th.ident is not None
            self._by_ident[th.ident] = v
            self._runnable.append(v)
        return _Handle(self, v, th)

    def call_at(self, t: float, fn: Callable[[], None]) -> None:
        """Run ``fn`` when virtual time reaches ``t`` (never before now), in whichever thread
        the scheduler is in: it must not block on the clock."""
        with self._lock:
            heapq.heappush(self._timers, (max(t, self.now), next(self._order), None, fn))

    def call_later(self, delay: float, fn: Callable[[], None]) -> None:
        self.call_at(self.now + max(delay, 0.0), fn)

    # ------------------------------------------------------------------ blocking
    def sleep(self, seconds: float) -> None:
        me = self._me()
        self._block(me, max(seconds, 0.0))

    def _block(self, me: _VThread, timeout: float | None) -> bool:
        """Park ``me`` until a notify (True) or ``timeout`` virtual seconds (False)."""
        with self._lock:
            me.token += 1
            me.woken = False
            if timeout is not None:
                heapq.heappush(self._timers, (self.now + timeout, next(self._order), me, me.token))
        self._switch(me)
        return me.woken

    def _wake(self, v: _VThread, token: int) -> None:
        """Make ``v`` runnable if it still sits in block ``token`` (held: the lock)."""
        if v.token == token and not v.done:
            v.token += 1
            v.woken = True
            self._runnable.append(v)

    def _switch(self, me: _VThread, leaving: bool = False) -> None:
        """Hand the baton to the next runnable thread (advancing time while there is none) and,
        unless ``leaving``, wait until ``me`` gets it back."""
        if self._closing:
            if leaving:
                return
            if me is not self._root:
                raise _Shutdown
        with self._lock:
            nxt = self._next()
            self.switches += 1
            if nxt is not me:
                self.now += self.step
        if nxt is not me:
            nxt.baton.release()
            if leaving:
                return
            me.baton.acquire()
            if self._closing and me is not self._root:
                raise _Shutdown
        if me is self._root and self._failure is not None:
            exc, self._failure = self._failure, None
            raise exc

    def _next(self) -> _VThread:
        """The next thread to run (held: the lock); the root with ``_failure`` set when none can."""
        while not self._runnable:
            if self._failure is not None:
                return self._give_root()
            if not self._timers:
                self._failure = Deadlock("virtual clock: every thread is blocked and nothing is due")
                return self._give_root()
            t, _, who, what = heapq.heappop(self._timers)
            if t > self._limit:
                self._failure = Deadlock(f"virtual clock: the time limit passed ({t:.3f} s)")
                return self._give_root()
            self.now = max(self.now, t)
            if who is None:
                try:
                    what()
                except BaseException as exc:  # noqa: BLE001 - the root raises it
                    self._failure = exc
            else:
                if who.token == what:
                    who.token += 1
                    who.woken = False
                    self._runnable.append(who)
        return self._runnable.popleft()

    def _give_root(self) -> _VThread:
        root = self._root
        assert root is not None
        root.token += 1
        return root

    # ------------------------------------------------------------------ conditions, events
    def condition(self, lock: Any = None) -> threading.Condition:
        return _VCondition(self, lock)

    def event(self) -> threading.Event:
        return _VEvent(self)  # type: ignore[return-value]  # duck-typed: set / is_set / wait / clear

    def _notify_join(self, v: _VThread) -> None:
        with self._lock:
            waiters = self._joiners.pop(id(v), [])
            for w, token in waiters:
                self._wake(w, token)

    def _join(self, v: _VThread, timeout: float | None) -> None:
        me = self._me()
        if v.done or me is v:
            return
        with self._lock:
            self._joiners.setdefault(id(v), []).append((me, me.token + 1))
        self._block(me, timeout)

    def _shutdown(self) -> None:
        """The root's run ended: every thread still parked is unwound (``_Shutdown``)."""
        with self._lock:
            self._closing = True
            parked = [v for v in self._by_ident.values() if v is not self._root and not v.done]
        for v in parked:
            v.baton.release()


class _Handle:
    """A thread the virtual clock started: ``join(timeout)`` on virtual time."""

    def __init__(self, clock: VirtualClock, v: _VThread, th: threading.Thread) -> None:
        self._clock, self._v, self.thread = clock, v, th
        self.name, self.ident = v.name, th.ident

    def join(self, timeout: float | None = None) -> None:
        self._clock._join(self._v, timeout)

    def is_alive(self) -> bool:
        return not self._v.done


class _VCondition(threading.Condition):
    """A condition whose ``wait`` blocks on the virtual clock; ``notify`` makes its waiters
    runnable (they run once the notifier blocks)."""

    def __init__(self, clock: VirtualClock, lock: Any = None) -> None:
        super().__init__(lock)
        self._clock = clock
        self._vwaiters: list[tuple[_VThread, int]] = []

    def wait(self, timeout: float | None = None) -> bool:
        if not self._is_owned():  # type: ignore[attr-defined]  # threading.Condition's own
            raise RuntimeError("cannot wait on un-acquired lock")
        clock = self._clock
        me = clock._me()
        self._vwaiters.append((me, me.token + 1))
        saved = self._release_save()  # type: ignore[attr-defined]
        try:
            return clock._block(me, timeout)
        finally:
            self._acquire_restore(saved)  # type: ignore[attr-defined]
            self._vwaiters = [w for w in self._vwaiters if w[0] is not me]

    def wait_for(self, predicate: Callable[[], Any], timeout: float | None = None) -> Any:
        end = None if timeout is None else self._clock.now + timeout
        result = predicate()
        while not result:
            left = None if end is None else end - self._clock.now
            if left is not None and left <= 0:
                break
            self.wait(left)
            result = predicate()
        return result

    def notify(self, n: int = 1) -> None:
        if not self._is_owned():  # type: ignore[attr-defined]
            raise RuntimeError("cannot notify on un-acquired lock")
        with self._clock._lock:
            woken, self._vwaiters = self._vwaiters[:n], self._vwaiters[n:]
            for v, token in woken:
                self._clock._wake(v, token)

    def notify_all(self) -> None:
        self.notify(len(self._vwaiters))


class _VEvent:
    """``threading.Event`` on the virtual clock."""

    def __init__(self, clock: VirtualClock) -> None:
        self._cond = _VCondition(clock, threading.Lock())
        self._flag = False

    def is_set(self) -> bool:
        return self._flag

    def set(self) -> None:
        with self._cond:
            self._flag = True
            self._cond.notify_all()

    def clear(self) -> None:
        with self._cond:
            self._flag = False

    def wait(self, timeout: float | None = None) -> bool:
        with self._cond:
            return bool(self._cond.wait_for(lambda: self._flag, timeout))
