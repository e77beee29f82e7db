"""Processes the runner starts (the node under test, the embedded reference node): they
die with the runner, even when the runner is killed with SIGKILL, and what they said is
kept, bounded, as evidence.

- **Parent-death signal**: on Linux each spawned process gets ``PR_SET_PDEATHSIG`` =
  SIGKILL (prctl(2)), so it is killed the moment the runner dies, however it dies. No Python
  runs in the child between fork and exec (CPython documents ``preexec_fn`` as unsafe while
  threads run, and the runner's threads do): the command is started through util-linux's
  ``setpriv --pdeathsig KILL`` (setpriv(1)), then ``sh``, which checks that its parent is
  still the runner (one that died before the signal was set would not send it: prctl(2)
  advises this check) and execs the command: the pid is the node's own throughout.
  The signal is the forking *thread*'s (prctl(2)): a process started from a thread that
  ends would be killed then, so every process started off the main thread is forked by one
  spawner thread that lives as long as the runner (:func:`popen`).
  Without ``setpriv`` (not Linux, util-linux older than 2.33) the reaper alone covers it.
- **Reaper**: a node's own children (``sh -c "python node.py; ..."``) do not inherit that
  signal, so a tiny watchdog process (its own session, so a signal to the runner's group
  does not take it too) holds the read end of a pipe; the runner writes each process
  group it starts. When the pipe closes, the runner is gone: the reaper kills every group
  it was told about, then exits. A runner that closes normally tells it first
  (``forget``).
- **Run delay at the end**: a process's run delay (D-7, ``harness.run_delay``) lives in
  ``/proc/<pid>`` only until it is reaped. A node that ends by itself (a manager that closes
  once its mission is done) is reaped by the first ``poll`` or ``wait`` that finds it gone,
  before the runner stops it; so each of them first asks ``waitid(..., WEXITED | WNOWAIT)``
  (waitid(2): the child is left waitable, a zombie whose ``/proc/<pid>`` is still there),
  reads the run delay then, and only then reaps (:class:`_Popen`): a stall after its last
  datagram stays known (:meth:`ManagedProcess.run_delay`).
- **Output**: stdout and stderr are read by two threads into bounded line buffers (the
  last ``TAIL_LINES`` lines of each, lines cut at ``LINE_CHARS``), so a chatty node can
  run for hours without filling a disk or the runner's memory.
"""

from __future__ import annotations

import collections
import contextlib
import errno
import logging
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from typing import IO, Any, cast

from mcp_conform.harness.run_delay import run_delay_ns

__all__ = ["SPAWN_STARTUP_S", "Reaper", "ManagedProcess", "deathsig_argv", "reaper"]

#: How long a process the runner spawned (node, manager, backend) gets to show itself before
#: the run is a setup error: a loaded host starts processes slowly, for reasons that are not
#: the protocol's
SPAWN_STARTUP_S = 20.0
TAIL_LINES = 40
REPORT_LINES = 40  # lines kept of a sanitizer report's head
LINE_CHARS = 400

_REAPER_CODE = r"""
import os, signal, sys
groups = set()
buf = b""
fd = int(sys.argv[1])
while True:
    try:
        chunk = os.read(fd, 4096)
    except InterruptedError:
        continue
    except OSError:
        chunk = b""
    if not chunk:
        break
    buf += chunk
    *lines, buf = buf.split(b"\n")
    for ln in lines:
        op, _, pgid = ln.partition(b" ")
        try:
            (groups.add if op == b"+" else groups.discard)(int(pgid))
        except ValueError:
            pass
for pgid in groups:
    try:
        os.killpg(pgid, signal.SIGKILL)
    except OSError:
        pass
"""


#: run by ``sh -c`` once setpriv has set the death signal: $0 is the runner's pid, "$@" the
#: command; a runner that died before the signal was set is no longer the parent (137: as
#: if killed, which is what the signal would have done)
_GUARD = 'test "$PPID" = "$0" || exit 137; exec "$@"'
_LOG = logging.getLogger(__name__)
_WRAPPER: list[str] | None = None
_PROBED = False


def _wrapper() -> list[str] | None:
    """``[setpriv, --pdeathsig, KILL, --, sh, -c, GUARD]`` if this system runs it (probed
    once per runner: a setpriv without ``--pdeathsig`` exits 1), else None."""
    global _WRAPPER, _PROBED
    if _PROBED:
        return _WRAPPER
    _PROBED = True
    setpriv, sh = shutil.which("setpriv"), shutil.which("sh")
    if not sys.platform.startswith("linux") or setpriv is None or sh is None:
        _LOG.debug("no setpriv(1) here: processes are not given a parent-death signal; "
                   "the reaper alone kills them when the runner dies")
        return None
    argv = [setpriv, "--pdeathsig", "KILL", "--", sh, "-c", _GUARD]
    try:
        ok = subprocess.run([*argv, str(os.getpid()), sh, "-c", "exit 0"], stdin=subprocess.DEVNULL,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            timeout=SPAWN_STARTUP_S).returncode == 0
    except (OSError, subprocess.SubprocessError):
        ok = False
    if not ok:
        _LOG.debug("%s --pdeathsig failed: processes are not given a parent-death signal; "
                   "the reaper alone kills them when the runner dies", setpriv)
        return None
    _WRAPPER = argv
    return _WRAPPER


def _check_executable(command: str) -> None:
    """The OSError Popen would raise for a command that cannot be run (the wrapper is
    found, so the error would otherwise be the wrapper's exit 127, not an exception)."""
    path = command if os.sep in command else shutil.which(command)
    if path is None or not os.path.exists(path):
        raise FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT), command)
    if os.path.isdir(path) or not os.access(path, os.X_OK):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), command)


def deathsig_argv(argv: list[str]) -> list[str]:
    """``argv`` started so that the kernel SIGKILLs it when the calling thread's process
    dies (see the module docstring); ``argv`` itself where setpriv is not available. Raises
    OSError, as Popen would, for a command that cannot be run."""
    wrapper = _wrapper()
    if wrapper is None or not argv:
        return argv
    _check_executable(argv[0])
    return [*wrapper, str(os.getpid()), *argv]


class Reaper:
    """The watchdog process (see the module docstring). One per runner process."""

    def __init__(self) -> None:
        self._w: int | None = None
        self._proc: subprocess.Popen[bytes] | None = None
        self._lock = threading.Lock()

    def _start(self) -> None:
        r, w = os.pipe()
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-I", "-S", "-c", _REAPER_CODE, str(r)], pass_fds=(r,),
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                start_new_session=True)
        except OSError:
            os.close(w)
            self._proc = None
            return
        finally:
            os.close(r)
        os.set_inheritable(w, False)
        self._w = w

    def _write(self, line: str) -> None:
        with self._lock:
            if self._w is None and self._proc is None:
                self._start()
            if self._w is None:
                return
            with contextlib.suppress(OSError):
                os.write(self._w, line.encode())

    def watch(self, pgid: int) -> None:
        self._write(f"+ {pgid}\n")

    def forget(self, pgid: int) -> None:
        self._write(f"- {pgid}\n")


_REAPER: Reaper | None = None


def reaper() -> Reaper:
    global _REAPER
    if _REAPER is None:
        _REAPER = Reaper()
    return _REAPER


class _Tail:
    """The last lines a stream wrote, bounded."""

    def __init__(self, stream: IO[bytes]) -> None:
        self.lines: collections.deque[str] = collections.deque(maxlen=TAIL_LINES)
        #: the head of the first sanitizer report (its ERROR line and what follows), kept
        #: whole however long the output grows after it
        self.report: list[str] = []
        #: the head of the latest cause of death written: a sanitizer report, or C++'s
        #: "terminate called after throwing ..." line (under ASan's halt_on_error=0 the first
        #: report is seldom what killed the process)
        self.last_cause: list[str] = []
        #: when each was read (time.monotonic()): the first report's first line, the latest
        #: cause's (what a death is attributed by: the case sent last before it, issue 36)
        self.report_at: float | None = None
        self.cause_at: float | None = None
        self.thread = threading.Thread(target=self._read, args=(stream,), daemon=True,
                                       name="mcp-conform-node-output")
        self.thread.start()

    def _read(self, stream: IO[bytes]) -> None:
        with contextlib.suppress(OSError, ValueError):
            for raw in iter(stream.readline, b""):
                text = raw.decode("utf-8", "replace").rstrip("\r\n")
                text = text if len(text) <= LINE_CHARS else text[:LINE_CHARS] + " ..."
                self.lines.append(text)
                starts = "Sanitizer:" in text and "ERROR" in text or "runtime error:" in text
                if (self.report and len(self.report) < REPORT_LINES) or (not self.report and starts):
                    if not self.report:
                        self.report_at = time.monotonic()
                    self.report.append(text)
                if starts or text.startswith("terminate called"):
                    self.last_cause, self.cause_at = [text], time.monotonic()
                elif self.last_cause and len(self.last_cause) < REPORT_LINES \
                        and not self.last_cause[0].startswith("terminate called"):
                    self.last_cause.append(text)
        with contextlib.suppress(OSError):
            stream.close()

    def tail(self, n: int) -> list[str]:
        return list(self.lines)[-n:]


class _Spawner:
    """The one thread that forks the processes started off the main thread: it ends only with
    the runner, so their parent-death signal means the runner's death, not a worker's end."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._jobs: list[tuple[Callable[[], object], list[object], threading.Event]] = []
        self._wake = threading.Condition(self._lock)
        self._thread: threading.Thread | None = None

    def run(self, fn: Callable[[], object]) -> object:
        box: list[object] = []
        done = threading.Event()
        with self._lock:
            if self._thread is None or not self._thread.is_alive():
                self._thread = threading.Thread(target=self._loop, name="procs-spawner", daemon=True)
                self._thread.start()
            self._jobs.append((fn, box, done))
            self._wake.notify()
        done.wait()
        if isinstance(box[0], BaseException):
            raise box[0]
        return box[0]

    def _loop(self) -> None:
        while True:
            with self._lock:
                while not self._jobs:
                    self._wake.wait()
                fn, box, done = self._jobs.pop(0)
            try:
                box.append(fn())
            except BaseException as exc:  # handed to the caller, raised there
                box.append(exc)
            done.set()


_SPAWNER = _Spawner()


#: waitid(2) with WNOWAIT: an ended child looked at without reaping it (Linux, most Unixes)
_PEEK = hasattr(os, "waitid") and hasattr(os, "WNOWAIT") and hasattr(os, "P_PID")


class _Popen(subprocess.Popen[bytes]):
    """A ``Popen`` that reads its process's run delay between its exit and its reaping
    (``end_run_delay``; see the module docstring): every ``poll`` and ``wait`` -- the runner's
    liveness checks, a stop's wait, a caller's ``proc.wait`` -- first looks for the exit with
    ``WNOWAIT``. Where waitid cannot leave a child waitable, a plain ``Popen``."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.end_run_delay: int | None = None
        self._end_lock = threading.Lock()
        super().__init__(*args, **kwargs)

    def _ended(self, block: bool = False) -> bool:
        """Whether the process has ended (not necessarily reaped yet); its run delay is read the
        first time it is found so, while its zombie still has ``/proc/<pid>``."""
        if self.returncode is not None or not _PEEK:
            return self.returncode is not None
        flags = os.WEXITED | os.WNOWAIT | (0 if block else os.WNOHANG)
        try:
            info = os.waitid(os.P_PID, self.pid, flags)
        except ChildProcessError:
            return True  # already reaped (by another waiter)
        if info is None:
            return False
        with self._end_lock:
            if self.end_run_delay is None and self.returncode is None:
                self.end_run_delay = run_delay_ns(self.pid)
        return True

    def poll(self) -> int | None:
        self._ended()
        return super().poll()

    def wait(self, timeout: float | None = None) -> int:
        if self.returncode is None and _PEEK:
            try:
                timeout = self._until_ended(timeout)
            except KeyboardInterrupt:  # as Popen.wait: a moment for the child, which got ^C too
                with contextlib.suppress(subprocess.TimeoutExpired):
                    super().wait(0.25)
                raise
        return super().wait(timeout)

    def _until_ended(self, timeout: float | None) -> float | None:
        """Wait for the end without reaping (up to ``timeout`` s: TimeoutExpired past it);
        the timeout left for the reaping, which is at once."""
        if timeout is None:
            self._ended(block=True)
            return None
        end, pause = time.monotonic() + timeout, 0.0005
        while not self._ended():
            left = end - time.monotonic()
            if left <= 0:
                raise subprocess.TimeoutExpired(self.args, timeout)
            time.sleep(min(pause, left))
            pause = min(2 * pause, 0.05)  # as Popen.wait's own polling
        return max(end - time.monotonic(), 0.05)


def popen(argv: list[str], **kwargs: Any) -> subprocess.Popen[bytes]:
    """``_Popen(deathsig_argv(argv), **kwargs)``, forked by the main thread or by the spawner
    thread (see the module docstring), never by a thread that may end first."""
    argv = deathsig_argv(argv)
    if threading.current_thread() is threading.main_thread():
        return _Popen(argv, **kwargs)
    return cast("subprocess.Popen[bytes]", _SPAWNER.run(lambda: _Popen(argv, **kwargs)))


class ManagedProcess:
    """A process of the run: own process group, parent-death signal, reaper, output kept."""

    def __init__(self, argv: list[str]) -> None:
        self.argv = argv
        self.proc = popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, start_new_session=True)
        reaper().watch(self.proc.pid)
        assert self.proc.stdout is not None and self.proc.stderr is not None
        self._out = _Tail(self.proc.stdout)
        self._err = _Tail(self.proc.stderr)

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def run_delay(self) -> int | None:
        """Its run delay (ns, D-7, ``harness.run_delay``): now while it runs; once it has ended,
        as it was between its exit and its reaping (:class:`_Popen`: a process that ended by
        itself before the runner stopped it is known too, never a later process with its
        pid); None where ``/proc`` does not say."""
        if self.proc.returncode is None:
            now = run_delay_ns(self.proc.pid)
            if now is not None and self.proc.returncode is None:
                return now
        return getattr(self.proc, "end_run_delay", None)

    @property
    def returncode(self) -> int | None:
        return self.proc.poll()

    def output(self, lines: int = 12) -> tuple[list[str], list[str]]:
        """The last ``lines`` lines of stdout and of stderr (after the process ended, all of
        what it wrote has been read)."""
        if not self.alive():
            for t in (self._out, self._err):
                t.thread.join(timeout=0.5)
        return self._out.tail(lines), self._err.tail(lines)

    def last_cause(self) -> list[str]:
        """The head of the latest sanitizer report, or the latest "terminate called after
        throwing" line, whichever came last on stderr ([] if neither)."""
        if not self.alive():
            self._err.thread.join(timeout=0.5)
        return list(self._err.last_cause)

    def cause_time(self) -> float | None:
        """When the latest cause's first line was read (``time.monotonic()``), None if none."""
        if not self.alive():
            self._err.thread.join(timeout=0.5)
        return self._err.cause_at

    def report_time(self) -> float | None:
        """When the first sanitizer report's first line was read, None if none."""
        return self._err.report_at

    def sanitizer_report(self) -> list[str]:
        """The head of the first AddressSanitizer/UBSan report on stderr ([] if none)."""
        if not self.alive():
            self._err.thread.join(timeout=0.5)
        return list(self._err.report)

    def stop(self, grace: float = 2.0) -> None:
        """SIGTERM to the group, then SIGKILL to whatever is left of it; never raises."""
        try:
            if self.alive():
                with contextlib.suppress(ProcessLookupError, PermissionError):
                    os.killpg(self.proc.pid, signal.SIGTERM)
                with contextlib.suppress(subprocess.TimeoutExpired):
                    self.proc.wait(timeout=grace)
        finally:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(self.proc.pid, signal.SIGKILL)  # the whole group, stragglers included
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.proc.wait(timeout=2.0)
            reaper().forget(self.proc.pid)
