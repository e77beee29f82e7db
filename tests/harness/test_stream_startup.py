"""A backend the Nsqd session spawned gets SPAWN_STARTUP_S to show itself live: a process just
started on a loaded host is slow for reasons that are not the protocol's (a CI run beside a
fuzz campaign: the embedded reference backend missed the attached allowance of 3.5 s). (An attached
backend keeps connect_timeout_s + update_gap_max_s: tests/nsqd/test_conform_nsqd.py.)"""

from __future__ import annotations

import shlex
import sys
import time

from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.nsqd_session import StreamSession
from mcp_conform.harness.procs import SPAWN_STARTUP_S
from mcp_conform.spec import NSQD

#: listens, and sends each connection its first bytes only after ``delay`` seconds (a length
#: prefix no frame has: bytes the runner cannot parse prove it live too, NSQD-FRM-1's to judge)
SLOW = ("import socket, sys, threading, time\n"
        "s = socket.socket(); s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)\n"
        "s.bind((sys.argv[1], int(sys.argv[2]))); s.listen(8)\n"
        "def serve(c):\n"
        "    time.sleep(float(sys.argv[3])); c.sendall(b'\\xff' * 8); time.sleep(1); c.close()\n"
        "while True:\n"
        "    threading.Thread(target=serve, args=(s.accept()[0],), daemon=True).start()\n")


def _session(delay: float) -> StreamSession:
    cmd = f"{shlex.quote(sys.executable)} -c {shlex.quote(SLOW)} {{target_host}} {{target_port}} {delay}"
    return StreamSession(RunConfig(target=None, spawn=cmd))


def test_a_spawned_backend_slow_to_speak_is_live_within_the_spawn_allowance():
    attached = float(NSQD.params["connect_timeout_s"]) + float(NSQD.params["update_gap_max_s"])
    assert attached + 1.5 < SPAWN_STARTUP_S
    s = _session(attached + 1.5)
    t0 = time.monotonic()
    try:
        s.start()  # raised SetupError ("sent no UPDATE") with the attached allowance
        assert time.monotonic() - t0 >= attached
    finally:
        s.close()
