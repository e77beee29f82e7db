"""Recording off the hot path: :class:`BackgroundRecorder` and its writer process.

A node records every datagram it sends and receives; decoding, JSON and MCAP cost about
9 µs a record, several times a reference node's work per ACK. So a node does not record
in-process: each call only timestamps the record and appends it to a deque (well under a
microsecond); a flusher thread ships the deque every ``FLUSH_S`` seconds, as one
``marshal``-ed batch, down a pipe to a writer process (``python -m mcp_conform.traceio.background
FILE``) that runs :class:`~traceio.recorder.McapRecorder` on another core. ``live``
(``--live``): the writer also serves the records over the Foxglove WebSocket protocol
(:mod:`traceio.live`), off the node's hot path as well, and stops serving when it ends.

The writer runs at nice 19, so it takes mostly CPU time nothing else wants: the node under
load gets the CPU first and the writer catches up from the pipe and the backlog (at the end
at normal priority where the system lets it change back). It runs in its own session, so a
signal to the node's process group (Ctrl-C, the
runner's ``killpg``) does not reach it; it finishes the file when the pipe closes, which
happens when the node closes the recorder or dies in any way, SIGKILL included. So the file
is valid whenever the node stops, with everything recorded up to ``FLUSH_S`` before a
sudden death. ``close()`` waits for the writer to finish.
"""

from __future__ import annotations

import contextlib
import marshal
import os
import struct
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from mcp_conform.traceio import recorder as _rec

__all__ = ["BackgroundRecorder"]

FLUSH_S = 0.05
#: Records kept waiting for the writer before new ones are dropped (and counted).
MAX_BACKLOG = 2_000_000
_LEN = struct.Struct("<I")


def _addr(addr: Any) -> Any:
    if isinstance(addr, (tuple, list)):
        return tuple(addr[:2])
    return addr


class BackgroundRecorder:
    """:class:`~traceio.recorder.McapRecorder`'s methods, written by a writer process."""

    def __init__(self, path: str | Path | None, *, library: str = "mcp-conform",
                 metadata: Mapping[str, str] | None = None, local: Any = None,
                 live: tuple[str, int] | None = None) -> None:
        self.path = Path(path) if path is not None else None
        #: the recording socket's address: the default ``local`` of datagrams (settable)
        self.local = _addr(local)
        self.dropped = 0
        #: ``ws://HOST:PORT`` of the writer's live server (``live``: its (host, port))
        self.live_url: str | None = None
        self._closed = False
        self._queue: deque[tuple[str, tuple[Any, ...]]] = deque()
        if self.path is not None:
            try:
                open(self.path, "wb").close()  # noqa: SIM115 - one-line error now, not in the writer
            except OSError as exc:
                raise _rec.RecorderError(f"--capture: cannot write {str(self.path)!r}: {exc.strerror}") from None
        argv = [sys.executable, "-m", "mcp_conform.traceio.background", str(self.path) if self.path is not None else "-"]
        if live is not None:
            argv += ["--live", f"{live[0]}:{live[1]}"]
        try:
            self._proc = subprocess.Popen(argv, stdin=subprocess.PIPE,
                                          stdout=subprocess.PIPE if live is not None else subprocess.DEVNULL,
                                          start_new_session=True)
        except OSError as exc:
            raise _rec.RecorderError(f"--capture: cannot start the capture writer: {exc.strerror}") from None
        if live is not None:
            self.live_url = self._live_started()
        self._lock = threading.Lock()  # one writer of the pipe at a time
        self._wake = threading.Event()
        self._queue.append(("__init__", (library, dict(metadata or {}), self.local)))
        self._thread = threading.Thread(target=self._flush_loop, name="mcap-flusher", daemon=True)
        self._thread.start()
        _rec.OPEN.add(self)

    def _live_started(self) -> str:
        """The writer's first line: its live server's URL, or why it has none (a RecorderError)."""
        out = self._proc.stdout
        assert out is not None
        line = out.readline().decode("utf-8", "replace").strip()  # the writer says at once
        out.close()
        if line.startswith("ws://"):
            return line
        with contextlib.suppress(OSError):
            if self._proc.stdin is not None:
                self._proc.stdin.close()
        self._proc.wait(timeout=10)
        raise _rec.RecorderError(line.removeprefix("error: ") or "--live: the capture writer did not start")

    @property
    def closed(self) -> bool:
        return self._closed

    # ------------------------------------------------------------------ recording
    def _put(self, name: str, args: tuple[Any, ...]) -> None:
        if self._closed:
            return
        if len(self._queue) >= MAX_BACKLOG:
            self.dropped += 1
            return
        self._queue.append((name, args))

    def datagram(self, direction: str, data: bytes, addr: Any, t_ns: int | None = None,
                 local: Any = None, run_delay: int | None = None) -> None:
        if direction not in ("tx", "rx"):
            raise ValueError(f"datagram direction must be 'tx' or 'rx', not {direction!r}")
        self._put("datagram", (direction, bytes(data), _addr(addr),
                               time.time_ns() if t_ns is None else int(t_ns),
                               self.local if local is None else _addr(local),
                               None if run_delay is None else int(run_delay)))

    def burst(self, direction: str, cycle: Iterable[bytes], count: int, addr: Any,
              first_t_ns: int, last_t_ns: int, local: Any = None) -> None:
        if direction not in ("tx", "rx"):
            raise ValueError(f"burst direction must be 'tx' or 'rx', not {direction!r}")
        self._put("burst", (direction, [bytes(d) for d in cycle], int(count), _addr(addr),
                            int(first_t_ns), int(last_t_ns), self.local if local is None else _addr(local)))

    def mavlink(self, direction: str, frame: bytes, t_ns: int | None = None,
                msg_type: str | None = None, drone: int | None = None) -> None:
        if direction not in ("tx", "rx"):
            raise ValueError(f"mavlink direction must be 'tx' or 'rx', not {direction!r}")
        self._put("mavlink", (direction, bytes(frame), time.time_ns() if t_ns is None else int(t_ns),
                              msg_type, drone))

    def case_mark(self, case_id: str, event: str, t_ns: int | None = None,
                  outcome: str | None = None, rules: tuple[str, ...] | list[str] = (),
                  evidence: str | None = None) -> None:
        if event not in ("start", "end"):
            raise ValueError(f"case_mark event must be 'start' or 'end', not {event!r}")
        self._put("case_mark", (case_id, event, time.time_ns() if t_ns is None else int(t_ns),
                                outcome, list(rules), evidence))

    def log(self, message: str, level: str = "info", name: str = "mcp-conform", t_ns: int | None = None) -> None:
        self._put("log", (str(message), level, str(name), time.time_ns() if t_ns is None else int(t_ns)))

    def add_metadata(self, name: str, values: Mapping[str, Any]) -> None:
        self._put("add_metadata", (name, {str(k): str(v) for k, v in values.items()}))

    # ------------------------------------------------------------------ shipping
    def _ship(self) -> bool:
        """Send what is queued; False when the writer is gone."""
        queue = self._queue
        n = len(queue)
        if not n:
            return True
        batch = [queue.popleft() for _ in range(n)]
        blob = marshal.dumps(batch)
        stdin = self._proc.stdin
        try:
            with self._lock:
                assert stdin is not None
                stdin.write(_LEN.pack(len(blob)))
                stdin.write(blob)
                stdin.flush()
        except (BrokenPipeError, OSError, ValueError):
            return False
        return True

    def _flush_loop(self) -> None:
        while not self._closed:
            self._wake.wait(FLUSH_S)
            if not self._ship():
                return

    def flush(self) -> None:
        """Hand everything recorded so far to the writer (it may not be on disk yet)."""
        self._ship()

    def close(self, timeout: float = 30.0) -> None:
        """Ship the rest, close the pipe and wait for the writer to finish the file."""
        if self._closed:
            return
        self._closed = True
        self._wake.set()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout=5.0)
        self._ship()
        try:
            if self._proc.stdin is not None:
                self._proc.stdin.close()
        except OSError:
            pass
        try:
            self._proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:  # it finishes on its own; we do not wait longer
            pass
        _rec.OPEN.discard(self)

    def __enter__(self) -> BackgroundRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _read_exact(stream: Any, n: int) -> bytes:
    chunks = []
    while n:
        chunk = stream.read(n)
        if not chunk:
            break
        chunks.append(chunk)
        n -= len(chunk)
    return b"".join(chunks)


def writer_main(path: str | None, live: str | None = None) -> int:
    """The writer process: apply batches from stdin to an McapRecorder until EOF. ``live``
    (``HOST:PORT``): it also serves the records live (:mod:`traceio.live`) and prints the
    server's URL first on stdout (or ``error: ...``), for the node to show."""
    import signal

    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_IGN)  # finish the file on EOF, whatever the node gets
    server = None
    if live is not None:
        from mcp_conform.traceio.live import LiveError, LiveServer, parse_live

        try:
            server = LiveServer(*parse_live(live), name="mcp-node")
        except LiveError as exc:
            print(f"error: {exc}", flush=True)
            return 2
        print(server.url, flush=True)
    idle = _run_when_idle()
    stdin = sys.stdin.buffer
    rec: _rec.McapRecorder | None = None
    try:
        while True:
            head = _read_exact(stdin, _LEN.size)
            if len(head) < _LEN.size:
                break
            blob = _read_exact(stdin, _LEN.unpack(head)[0])
            try:
                batch = marshal.loads(blob)
            except (EOFError, ValueError, TypeError):
                break  # the node died mid-batch: keep what came whole
            for name, args in batch:
                if name == "__init__":
                    library, metadata, local = args
                    rec = _rec.McapRecorder(path, library=library, metadata=metadata, local=local,
                                            live=server.feed() if server is not None else None)
                elif rec is not None:
                    try:
                        getattr(rec, name)(*args)
                    except Exception as exc:  # noqa: BLE001 - one bad record must not lose the file
                        print(f"mcp capture writer: {name}: {exc}", file=sys.stderr)
    finally:
        if idle:  # the node is gone: finish at normal priority where the system lets us
            _run_normally()
        if rec is not None:
            rec.close()
        if server is not None:  # nothing left listening once the node is done
            server.stop()
    return 0


def _run_when_idle() -> bool:
    """Lowest priority (nice 19): the writer gets the CPU time the node does not want, so
    recording costs the node almost nothing; records wait in the pipe meanwhile. Unlike
    SCHED_IDLE it is never starved outright, and any user may do it. True when it worked."""
    try:
        os.nice(19 - os.nice(0))
        return True
    except (AttributeError, OSError):
        return False


def _run_normally() -> None:
    """Back to the usual priority to finish the file, where the system allows it (root)."""
    with contextlib.suppress(AttributeError, OSError):
        os.setpriority(os.PRIO_PROCESS, 0, 0)


if __name__ == "__main__":  # FILE ('-': none) [--live HOST:PORT]
    _args = sys.argv[1:]
    sys.exit(writer_main(None if _args[0] == "-" else _args[0],
                         _args[2] if len(_args) > 2 and _args[1] == "--live" else None))
