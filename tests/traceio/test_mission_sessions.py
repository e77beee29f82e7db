"""A run that restarts its node for each fresh mission (``mcp-conform --role manager``: a
manager runs one mission and is done): each mission is a session of the capture
(``McapRecorder.begin_segment``) and of the run's monitor (``judge.run_monitor.SessionMonitors``),
judged on its own and complete (the runner plays every drone). ``mcp-capture check`` gives the
live monitor's verdicts and violations rule by rule, by default, with ``--complete`` and merged
from xdist workers (``gw0/main``); the two missions judged as one trace would not (a manager
restarted: its numbers start again, the drones announce themselves again, a Start_Mission after
an End_Mission: false MCP-SEQ-1, MCP-BLK-2, MCP-BLK-6)."""

from __future__ import annotations

import json
from pathlib import Path

from mcp_conform.judge.judging import Params, judge
from mcp_conform.judge.monitor import TESTER
from mcp_conform.judge.run_monitor import MISSION_METADATA, SessionMonitors, mission_metadata
from mcp_conform.spec.codec import Action
from mcp_conform.traceio.merge import merge_captures
from mcp_conform.traceio.reader import Metadata, open_capture
from mcp_conform.traceio.recorder import NODE_METADATA, McapRecorder, run_metadata
from tests.conformance.runner_helpers import verdict_differences
from tests.judge.monitor_faults import rtx2_moves_on
from tests.judge.monitor_scripts import Script

RUNNER, MANAGER = ("127.0.0.1", 41001), ("127.0.0.1", 41002)


def _clean(seed: int, sent: tuple | None = None) -> Script:
    """A clean mission of a manager and the runner's drones 1 and 2; ``sent``: the items the
    manager's WP_Lists carry (default: the mission's)."""
    s = Script((1, 2), vehicle=False, seed=seed, **({"waypoints": sent} if sent is not None else {}))
    for d in s.drones:
        s.exchange(d, 0, Action.MISSION_READY, origin=TESTER)
        s.tick(0.02)
    for d in s.drones:
        s.exchange(0, d, Action.START_MISSION, acker_origin=TESTER)
        s.tick(0.01)
    for d in s.drones:
        s.exchange(0, d, Action.WP_LIST, tuple(s.items), acker_origin=TESTER)
        s.tick(0.01)
    for d in s.drones:
        s.exchange(0, d, Action.END_MISSION, acker_origin=TESTER)
    return s


def _record(path: Path, missions: dict[str, Script], *, sessions: bool = True,
            handed: tuple | None = None) -> SessionMonitors:
    """Record the missions one after the other as the manager role's runner does (the
    manager's datagrams received, the drones' sent, from the runner's one socket) and feed
    the same to a live monitor; returns it, finished."""
    rec = McapRecorder(path, metadata=run_metadata("mcp-conform", role="manager",
                                                   parameters={"rto": 0.2, "ack_window": 0.25}), local=RUNNER)
    mission = handed is not None  # the challenge-1 items the runner handed the manager, recorded
    live = SessionMonitors(rto=0.2, ack_window=0.25, broadcast_id=0xFFFF, node_id=0, node_addr=MANAGER,
                           complete=True, **({"challenge": 1, "waypoints": handed} if mission else {}))
    live.listen = RUNNER
    node = {"id": 0, "address": f"{MANAGER[0]}:{MANAGER[1]}", "complete": "true"}
    if not sessions:
        rec.add_metadata(NODE_METADATA, node)
        live.begin("run")
    t = 1_700_000_000_000_000_000
    for name, s in missions.items():
        if sessions:
            live.begin(name)
            rec.begin_segment(name, [(NODE_METADATA, node)]
                              + ([(MISSION_METADATA, mission_metadata(1, handed))] if mission else []))
        records = sorted(s.datagrams(), key=lambda r: r.t_ns)
        shift = t - records[0].t_ns
        for r in records:
            direction = "rx" if r.src_addr == s.addr(0) else "tx"  # the manager's, or the drones'
            rec.datagram(direction, r.data, MANAGER, r.t_ns + shift)
            live.observe(direction, r.data, MANAGER, r.t_ns + shift)
        end = records[-1].t_ns + shift + 1_000_000_000  # a case judges the mission a second later
        rec.case_mark(f"{name}/case", "start", end, rules=("MCP-RTX-2",))
        rec.case_mark(f"{name}/case", "end", end + 1000, outcome="passed", rules=("MCP-RTX-2",))
        live.mark(end)
        live.mark(end + 1000)
        t = end + 1_000_000_000  # the next manager starts a second later
    live.finish()
    rec.close()
    return live


def test_each_mission_is_a_session_judged_on_its_own_as_the_live_monitor_did(tmp_path):
    cap = tmp_path / "run.mcap"
    live = _record(cap, {"main": rtx2_moves_on(), "silent": _clean(1)}).to_json()
    assert live["complete"] and {v["rule"] for v in live["violations"]} == {"MCP-RTX-2"}, live["violations"]
    for complete in (False, True):
        j = judge(cap, Params(complete=complete))
        assert list(j.segments) == ["main", "silent"]
        assert all(s.params.complete for s in j.segments.values())  # as the run recorded it
        assert verdict_differences(live["rules"], j.verdicts) == []
        assert sorted((v.rule, v.node) for v in j.violations) == \
            sorted((v["rule"], v["node"]) for v in live["violations"])
    assert live["rules"]["0"]["MCP-RTX-2"] == "failed" and live["rules"]["0"]["MCP-BLK-1"] == "passed"


def test_the_missions_as_one_trace_would_be_false_alarms(tmp_path):
    """What the sessions are for: the same traffic without them is one trace of a manager
    that starts a second mission after its End_Missions (the judge cannot tell a restart)."""
    cap = tmp_path / "one.mcap"
    _record(cap, {"main": _clean(1), "silent": _clean(2)}, sessions=False)
    j = judge(cap, Params(complete=True))
    assert not j.segments and {v.rule for v in j.violations} & {"MCP-BLK-6", "MCP-SEQ-1", "MCP-BLK-2"}
    sessions = tmp_path / "run.mcap"
    live = _record(sessions, {"main": _clean(1), "silent": _clean(2)}).to_json()
    assert live["violations"] == [] and judge(sessions, Params(complete=True)).violations == []


def test_an_xdist_merge_keeps_each_workers_missions_apart(tmp_path):
    gw0, gw1 = tmp_path / "run.gw0.mcap", tmp_path / "run.gw1.mcap"
    a = _record(gw0, {"main": rtx2_moves_on(), "silent": _clean(3)}).to_json()
    b = _record(gw1, {"main": _clean(4), "silent": _clean(5)}).to_json()
    out = tmp_path / "run.mcap"
    merge_captures([gw0, gw1], out)
    cap = open_capture(out)
    runs = [r.data.get("segment") for r in cap if isinstance(r, Metadata) and r.name == NODE_METADATA]
    assert sorted(runs) == ["gw0/main", "gw0/silent", "gw1/main", "gw1/silent"]
    j = judge(out, Params())
    assert sorted(j.segments) == ["gw0/main", "gw0/silent", "gw1/main", "gw1/silent"]
    assert all(s.params.complete for s in j.segments.values())  # the worker's run metadata holds
    assert sorted((v.rule, v.node) for v in j.violations) == \
        sorted((v["rule"], v["node"]) for v in a["violations"] + b["violations"]) == [("MCP-RTX-2", 0)]


def test_the_mission_a_session_records_is_what_check_judges_its_lists_by(tmp_path):
    """The challenge and the items the manager was handed, recorded with each session: the
    live monitor and ``check`` compare the WP_List with them alike (a reversed list fails
    MCP-FLOW-4 in both); ``--challenge`` given by the user still wins."""
    from mcp_conform.captures.check import to_json, validate_json
    from tests.judge.monitor_scripts import WAYPOINTS

    wrong = tuple(reversed(WAYPOINTS))  # the manager sends the file's items reversed
    cap = tmp_path / "run.mcap"
    missions = {"main": _clean(6, wrong), "silent": _clean(7, wrong)}
    live = _record(cap, missions, handed=WAYPOINTS).to_json()
    assert {v["rule"] for v in live["violations"]} == {"MCP-FLOW-4"}, live["violations"]
    for complete in (False, True):
        j = judge(cap, Params(complete=complete))
        assert verdict_differences(live["rules"], j.verdicts) == []
        assert j.verdicts[0]["MCP-FLOW-4"] == "failed"
        assert j.params.challenge == 1 and j.params.challenge_source == "recorded"
        assert set(j.params.from_capture) >= {"rto", "ack_window", "challenge", "waypoints"}
        validate_json(json.loads(json.dumps(to_json(j, {}))))
    given = judge(cap, Params(challenge=2, given=frozenset({"challenge"})))
    assert given.params.challenge == 2 and "MCP-FLOW-4" not in {v.rule for v in given.violations}


def test_a_session_written_late_is_put_in_order_among_itself(tmp_path: Path) -> None:
    """A scenario run beside the main mission (``mcp-conform --role manager``) has its
    traffic held, then written as a session of its own once its case asks: with the times
    its datagrams arrived, seconds older than the main session's last records, and in the
    order the runner's threads saw them (a drone's ACK may be seen before the command it
    follows, a few ms older). Its live monitor put them in time order; the reader must too,
    in that session, or a WP_List sent before its Start_Mission's ACK (MCP-BLK-3) is judged
    as sent after it (CI: BLK-3 twice live, once offline)."""
    path = tmp_path / "late.mcap"
    rec = McapRecorder(path, local=("127.0.0.1", 7890))
    t = 1_700_000_000_000_000_000
    rec.begin_segment("main")
    for k in range(40):  # the main mission, 4 s of it
        rec.datagram("rx", b"main-%d" % k, ("127.0.0.1", 7889), t + k * 100_000_000)
    rec.begin_segment("silent")  # written now, with the times of 3 s ago
    late = t + 1_000_000_000
    for k, dt in enumerate([0, 30, 10, 20, 50, 40]):  # ms: seen out of order by a few ms
        rec.datagram("rx", b"silent-%d" % k, ("127.0.0.1", 7991), late + dt * 1_000_000)
    rec.close()
    times = [d.t_ns for d in open_capture(path).datagrams() if d.segment == "silent"]
    assert len(times) == 6 and times == sorted(times), [(x - late) // 1_000_000 for x in times]
