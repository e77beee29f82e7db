"""A backend found dead at a pipelined program's turnover (``Player.finish``: every client's
FIN, then a new connection) is the program's :class:`Hit`, as a death anywhere else in the
program is. The backend's own record of a death (``fuzz.nsqd_backend.Hit``) is no exception:
raised as it was, it ended a real backend's default campaign with "TypeError: exceptions must
derive from BaseException" (exit 2) once the engine mix reached the stateful engine."""

from __future__ import annotations

import os
import signal

import pytest

from mcp_conform.fuzz.nsqd_backend import Backend
from mcp_conform.fuzz.nsqd_mutators import Write
from mcp_conform.fuzz.nsqd_player import Hit, Op, Player, command_bytes
from tests.nsqd_backends.build import built_or_skip


@pytest.mark.nsqd
def test_a_death_seen_at_the_turnover_is_the_programs_hit(monkeypatch: pytest.MonkeyPatch) -> None:
    exe = built_or_skip()
    b = Backend(None, f"{exe} --host {{target_host}} --port {{target_port}} --update-period 0.1")
    p = Player(b, fast=True)
    try:
        p.play(Op("open", 0))
        p.play(Op("cmd", 0, (Write(command_bytes("TAKEOFF")),), "TAKEOFF", valid=True))
        # the death comes after the program's last look (``_judge``) and before the turnover's
        monkeypatch.setattr(p, "_judge", lambda: None)
        proc = b.session.proc
        assert proc is not None
        os.kill(proc.pid, signal.SIGKILL)
        proc.proc.wait(timeout=10)
        with pytest.raises(Hit) as got:
            p.finish()
        assert got.value.signature.oracle == "crash" and "SIGKILL" in got.value.signature.describe(), got.value
    finally:
        p.close()
        b.close()
