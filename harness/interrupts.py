"""SIGINT and SIGTERM during a run: the reports survive every signal.

The first signal stops the run: it raises ``KeyboardInterrupt`` in the main thread (pytest
then finishes the session: the case in progress, the reports, the node). Every later
signal only *hurries* the shutdown (``hurry`` becomes true: processes are killed without their
grace period) and never raises, so nothing can interrupt the writers. Once the run
finishes (``stop_raising()``) even the first signal only hurries; inside ``held()`` (a
capture record being written) the first signal waits for the block to end.

One ``Interrupts`` per process (``INTERRUPTS``), installed by ``mcp-conform`` before
anything else and by the pytest plugin when it runs under plain pytest. Other consumers
(a JUnit writer, CI glue) read ``INTERRUPTS.signals`` / ``hurry`` rather than install
their own handlers.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from typing import Any

__all__ = ["INTERRUPTS", "Interrupts"]

_SIGNALS = tuple(s for s in (getattr(signal, "SIGINT", None), getattr(signal, "SIGTERM", None)) if s is not None)


class Interrupts:
    def __init__(self) -> None:
        self.signals: list[str] = []  # names of the signals received, in order
        #: set by a second signal: stop processes without their grace period. A plain flag,
        #: not a threading.Event: a signal handler must take no lock (a signal landing while
        #: the handler held Event.set's lock re-entered it and deadlocked the run)
        self.hurry = False
        self._raising = True
        self._held = False
        self._pending = False
        self._old: dict[int, Any] = {}

    @property
    def interrupted(self) -> bool:
        return bool(self.signals)

    def reason(self) -> str:
        """The JSON report's error for an interrupted run: "interrupted by SIGTERM"."""
        return f"interrupted by {self.signals[0]}" if self.signals else "interrupted"

    def install(self) -> bool:
        """Take SIGINT and SIGTERM (main thread only); True when installed now."""
        if self._old or threading.current_thread() is not threading.main_thread():
            return False
        self.signals, self._raising, self._pending = [], True, False  # a new run (several may run in one process)
        self.hurry = False
        for sig in _SIGNALS:
            with contextlib.suppress(ValueError, OSError):
                self._old[sig] = signal.signal(sig, self._handle)
        return True

    def restore(self) -> None:
        for sig, old in self._old.items():
            with contextlib.suppress(ValueError, OSError, TypeError):
                signal.signal(sig, old)
        self._old.clear()

    def forked(self) -> None:
        """In a child forked from a process that installed these handlers (an instance of
        ``--parallel``): the handlers the process had before, and no state of the parent's run,
        as a process just started has; its own run installs them again."""
        self.restore()
        self.signals, self.hurry, self._raising, self._held, self._pending = [], False, True, False, False

    def _handle(self, signum: int, frame: Any) -> None:
        try:
            name = signal.Signals(signum).name
        except ValueError:
            name = str(signum)
        self.signals.append(name)
        if len(self.signals) == 1 and self._raising:
            if self._held or _in_import_machinery(frame):
                self._pending = True  # raised when the held block ends, else seen as `interrupted`
                return
            raise KeyboardInterrupt(name)
        self.hurry = True

    @contextlib.contextmanager
    def held(self) -> Iterator[None]:
        """Within: a first signal waits for the block to end before it stops the run (a
        capture record is never left half-written). Signals reach only the main thread, so
        elsewhere this does nothing."""
        if threading.current_thread() is not threading.main_thread():
            yield
            return
        saved, self._held = self._held, True
        try:
            yield
        finally:
            self._held = saved
            if not saved and self._pending:
                self._pending = False
                if self._raising:
                    raise KeyboardInterrupt(self.signals[0])

    def hold(self) -> None:
        """As :meth:`held`, across code a ``with`` block cannot wrap (pytest's own start-up:
        a signal landing in its argument parsing broke argparse's state, and the run ended
        with a traceback); :meth:`release` ends it. Main thread only."""
        if threading.current_thread() is threading.main_thread():
            self._held = True

    def release(self) -> None:
        """End :meth:`hold`: a first signal that came meanwhile stops the run now."""
        if threading.current_thread() is not threading.main_thread() or not self._held:
            return
        self._held = False
        if self._pending:
            self._pending = False
            if self._raising:
                raise KeyboardInterrupt(self.signals[0])

    def stop_raising(self) -> None:
        """From now on no signal raises (the run is finishing)."""
        self._raising = False


def _in_import_machinery(frame: Any) -> bool:
    """True when the signal landed in importlib's own code: an exception raised there may
    be in one of its weakref callbacks, where Python prints "Exception ignored in ..." with
    a traceback and swallows it. The run still stops: the runner checks ``interrupted``
    before every case."""
    return frame is not None and frame.f_code.co_filename.startswith("<frozen importlib")


INTERRUPTS = Interrupts()
