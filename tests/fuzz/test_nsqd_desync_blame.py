"""A command lost after a cut frame is NSQD-ROB-3's only if the cut made the difference.

NSQD-ROB-3: "Each connection is a new stream: the bytes of a frame cut by a closed connection
are discarded, never joined to the next connection's bytes." The stateful player names a
command whose effect does not show on the connection after a cut "desync: stream lost after
fin-mid-frame [NSQD-ROB-3]"; a backend that ignores every command loses it too, cut or no
cut, and breaks NSQD-MSG-3 ("A valid command takes its effect on the flight state"), not
NSQD-ROB-3. The flaky-crash campaign of tests/fuzz/test_blame.py (its processes ignore every
command once its two crashes are spent) confirmed that desync 3 of 3 as an NSQD-ROB-3 finding.
Triage now replays the minimal program without its cut: the same loss there is the
program's own, and the finding names it.
"""

from __future__ import annotations

import sys

import pytest

from mcp_conform.fuzz.nsqd_mutators import Write
from mcp_conform.fuzz.nsqd_player import Op, command_bytes

pytestmark = [pytest.mark.slow, pytest.mark.nsqd]

CMD = "TAKEOFF"  # its effect (HOVER) is not the deaf backend's GROUNDED


def _program() -> list[Op]:
    """A frame cut by FIN, then the command on the next connection (the campaign's shape)."""
    whole = command_bytes("SET_HOVERHEIGHT")
    return [Op("send", 0, (Write(whole[:16], end="fin"),), "fin-mid-frame", in_sync=False,
               note="SET_HOVERHEIGHT cut at 16 by FIN"),
            Op("open", 0),
            Op("cmd", 0, (Write(command_bytes(CMD)),), CMD, valid=True)]


def _triaged(tmp_path, spawn: str):
    """The program played (the player's verdict), then triaged as a campaign triages a
    stateful program's failure: (the player's hit, the findings)."""
    from mcp_conform.fuzz.nsqd_backend import Backend
    from mcp_conform.fuzz.nsqd_campaign import StreamCampaign
    from mcp_conform.fuzz.nsqd_stateful import play_program, triage_program
    from mcp_conform.fuzz.nsqd_triage import StreamTarget, StreamTriage

    b = Backend(None, spawn)
    hit = play_program(b, _program())
    if hit is None:
        b.close()
        return None, []
    c = StreamCampaign(None, spawn, 1, 20.0, None, tmp_path, engine="stateful")
    t = StreamTriage(target=StreamTarget(b), store=c.store, seed=1, duration=20.0)
    triage_program(t, b, hit, _program()).close()
    return hit, t.findings


def test_a_backend_deaf_to_every_command_is_no_desync(tmp_path):
    """tests/fuzz/servers/misbehaving_backend --mode deaf: the player sees the command lost
    after the cut (a desync, as the campaign saw it); the finding is the command's own effect,
    NSQD-MSG-3, replayed without the cut. Before the fix: "desync: stream lost after
    fin-mid-frame [NSQD-ROB-3]", 3 of 3."""
    spawn = (f"{sys.executable} -m tests.fuzz.servers.misbehaving_backend --bind {{target_host}}:{{target_port}} "
             "--mode deaf --lifetime 120")
    hit, findings = _triaged(tmp_path, spawn)
    assert hit is not None and hit.signature.rule == "NSQD-ROB-3", hit  # the player's suspicion
    assert [(f.signature.oracle, f.signature.rule) for f in findings] == [("effect", "NSQD-MSG-3")], \
        [f.signature for f in findings]
    assert all(o["what"] != "send" for o in findings[0].program), findings[0].program


def test_a_backend_that_joins_the_cut_frame_stays_nsqd_rob_3(tmp_path):
    """The C backend's stale-partial-frame fault (tests/nsqd_backends: the cut frame's bytes
    kept for the next connection) executes the command on a stream of its own: the cut makes
    the difference, and the finding stays NSQD-ROB-3 with the cut in its program."""
    from tests.nsqd_backends.build import built_or_skip

    exe = built_or_skip()
    spawn = f"{exe} --host {{target_host}} --port {{target_port}} --update-period 0.1 --fault stale-partial-frame"
    hit, findings = _triaged(tmp_path, spawn)
    assert hit is not None and hit.signature.rule == "NSQD-ROB-3", hit
    assert [f.signature.rule for f in findings] == ["NSQD-ROB-3"], [f.signature for f in findings]
    assert any(o["what"] == "send" for o in findings[0].program), findings[0].program
