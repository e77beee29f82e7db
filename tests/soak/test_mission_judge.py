"""``mcp-soak`` judges a mission by the suite's rules (issue 38, the Go manager's soak): what a
mission holds is the judge's (MCP-FLOW-2/3 and the challenge's FLOW rule, ``_judge``); the
exactly-once check (MCP-DUP-1, MCP-RTX-1) compares each drone's deliveries with what the manager
sent it -- its record, or, without one, its own view in the mission's capture.

It compared them with a fixed list (``expected_commands``: challenge 3, Start_Mission,
Obstacles_List, End_Mission), so a manager that sends the route too (Obstacles_List, then a
WP_List), which ``mcp-conform`` passes (MCP-FLOW-6: "the mission's obstacles as one
Obstacles_List", not only), failed every drone: "delivered Start_Mission,Obstacles_List,WP_List,
End_Mission, expected Start_Mission,Obstacles_List,End_Mission". The whole mission with such a
manager: tests/examples/test_go_manager.py."""

from __future__ import annotations

import json
from pathlib import Path

from mcp_conform.soak.mission import MissionResult, MissionSetup, _check_deliveries
from mcp_conform.spec.codec import Action, build_datagram
from mcp_conform.traceio.merge import merge_captures
from mcp_conform.traceio.recorder import McapRecorder

DRONES = (1, 2)
#: challenge 3 with its route: what the manager sends each drone
ROUTE_TOO = [Action.START_MISSION, Action.OBSTACLES_LIST, Action.WP_LIST, Action.END_MISSION]


def _mission(tmp_path: Path, delivered: dict[int, list[Action]], *, record: bool, twice: int | None = None) -> Path:
    """A mission's files: each drone's delivery log, the manager's record (``record``) and its
    view merged into ``mission.mcap``, what it sent being :data:`ROUTE_TOO` to each drone (each
    command in two copies, a retransmission repeats its seq); ``twice``: that drone delivered its
    first command twice."""
    view = tmp_path / "mission.manager.mcap"
    rec = McapRecorder(view, library="mcp-soak")
    seq, t = 100, 1_000_000_000
    sent = []
    for action in ROUTE_TOO:
        for drone in DRONES:
            data = build_datagram(drone, 0, seq, action)  # (payloads are not the exactly-once check's)
            for _copy in range(2):
                rec.datagram("tx", data, ("127.0.0.1", 9000 + drone), t, local=("127.0.0.1", 9000))
                t += 1_000_000
            sent.append([action.name, drone])
            seq += 1
    rec.close()
    merge_captures([view], tmp_path / "mission.mcap")
    if record:
        (tmp_path / "manager.json").write_text(json.dumps({"sent": sent, "outcome": "end_mission"}))
    for drone, actions in delivered.items():
        deliveries = [[a.name, 0, 100 + k] for k, a in enumerate(actions)]
        if drone == twice:
            deliveries.insert(1, deliveries[0])
        (tmp_path / f"drone{drone}.json").write_text(json.dumps({"deliveries": deliveries}))
    return tmp_path / "mission.mcap"


def _reasons(tmp_path: Path, capture: Path) -> list[str]:
    res = MissionResult(0, 1, 3, "")
    _check_deliveries(res, tmp_path, MissionSetup(impair=None, drones=DRONES), capture)  # type: ignore[arg-type]
    return res.reasons


def test_challenge_3_with_its_route_delivered_as_the_manager_sent_it_is_exactly_once(tmp_path):
    for record in (True, False):  # the manager's record, or its own view in the capture
        out = tmp_path / str(record)
        out.mkdir()
        capture = _mission(out, dict.fromkeys(DRONES, ROUTE_TOO), record=record)
        assert _reasons(out, capture) == [], record


def test_a_command_the_manager_sent_and_a_drone_missed_or_got_twice_is_found(tmp_path):
    for record in (True, False):
        out = tmp_path / str(record)
        out.mkdir()
        capture = _mission(out, {1: [a for a in ROUTE_TOO if a != Action.WP_LIST], 2: ROUTE_TOO},
                           record=record, twice=2)
        reasons = _reasons(out, capture)
        assert ("drone1: delivered Start_Mission,Obstacles_List,End_Mission, expected Start_Mission,Obstacles_List,"
                "WP_List,End_Mission (what the manager sent it, exactly once, in order)") in reasons, reasons
        assert any(r.startswith("drone2: delivered (src, seq) (0, 100) 2 times (MCP-DUP-1)") for r in reasons), reasons
