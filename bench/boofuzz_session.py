"""boofuzz, run as the fuzz benchmarks compare against it (bench/bench_fuzz.py for MCP,
bench/bench_fuzz_nsqd.py for Nsqd): one timed session, its output kept off stdout, its web
interface on a free port. Both benchmarks import it; neither imports the other."""

from __future__ import annotations

import contextlib
import io
import os
import socket
import sys
import tempfile
import threading
import time
from typing import Any

from mcp_conform.vehicle.ports import free_port


def web_port() -> int:
    """A free TCP port for boofuzz's web interface (it binds it itself)."""
    return free_port(kind=socket.SOCK_STREAM)


def timed_session(boofuzz: Any, kw: dict, requests: list[Any], seconds: float) -> tuple[int, float]:
    """A boofuzz Session of ``kw`` over ``requests``, stopped after ``seconds``: (cases fuzzed,
    seconds taken). Run in a temporary directory (boofuzz writes boofuzz-results/ where it runs),
    its banner kept off stdout, its web interface stopped."""
    cwd = os.getcwd()
    with tempfile.TemporaryDirectory() as tmp:
        os.chdir(tmp)
        try:
            with _quiet_stdout():
                session = boofuzz.Session(**kw)
                for req in requests:
                    session.connect(req)
                timer = threading.Timer(seconds, lambda: setattr(session, "_index_end", 0))
                timer.start()
                t0 = time.monotonic()
                try:
                    session.fuzz()
                finally:
                    elapsed = time.monotonic() - t0
                    timer.cancel()
                n = session.num_cases_actually_fuzzed
                if getattr(session, "web_interface_thread", None) is not None:
                    with contextlib.suppress(Exception):
                        session.web_interface_thread.stop()
        finally:
            os.chdir(cwd)
    return int(n), elapsed

@contextlib.contextmanager
def _quiet_stdout():  # noqa: ANN202
    """boofuzz's text logger writes to the process's stdout: send fd 1 to /dev/null."""
    sys.stdout.flush()
    saved = os.dup(1)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        with contextlib.redirect_stdout(io.StringIO()):
            yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)
