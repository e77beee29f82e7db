"""The simulator itself (issue 38, item 2): a schedule replays to the same trace and verdicts,
a clean link carries a whole mission, the link records what it made, stalls hold a party."""

from __future__ import annotations

import pytest

from mcp_conform.harness.impair import DelayQueue, Impairment, ImpairmentError, parse_impairment
from mcp_conform.sim.link import Link
from mcp_conform.sim.schedule import Schedule, run_schedule
from mcp_conform.sim.world import StallParams
from mcp_conform.spec.codec import Action, peek_header

BAD = parse_impairment("loss=0.2,dup=0.2,reorder=0.2,delay=0-2000ms,seed=0")


def _digest(o):  # the whole trace and every verdict
    return ({p: [tuple(r) for r in v] for p, v in o.world.views.items()},
            {k: [tuple(r.__dict__.values()) if hasattr(r, "__dict__") else r for r in link.records]
             for k, link in o.world.links.items()},
            o.judged.summary() if o.judged else None,
            {p: {r: v.status for r, v in e.items()} for p, e in o.judged.explained.items()} if o.judged else None)


@pytest.mark.parametrize("fault", [None, "no-ack", "wrong-seq-ack"])
def test_a_schedule_replays_to_the_same_trace_and_verdicts(fault):
    s = Schedule(seed=7, drones=2, challenge=2, items=2, down=BAD, up=BAD, fault=fault,
                 stalls=StallParams(count=2, max_len=2.0, span=20.0))
    assert _digest(run_schedule(s)) == _digest(run_schedule(Schedule.from_json(s.to_json())))


def test_another_seed_is_another_schedule():
    a, b = (run_schedule(Schedule(seed=n, down=BAD, up=BAD), judge=False) for n in (1, 2))
    assert a.world.views != b.world.views


@pytest.mark.parametrize("challenge", [1, 2, 3])
def test_a_clean_link_carries_the_whole_mission(challenge):
    o = run_schedule(Schedule(seed=3, drones=3, challenge=challenge, items=3))
    w = o.world
    assert w.manager.outcome == "end_mission" and not w.truncated
    assert all(d.outcome == "end_mission" and d.started and d.ended for d in w.drones.values())
    # every drone delivered each command once, in the manager's order (MCP-DUP-1, MCP-FLOW-3)
    for d in w.drones.values():
        got = [a for a, src, _ in d.delivered]
        assert got[0] == Action.START_MISSION and got[-1] == Action.END_MISSION
        assert len(got) == len({seq for _, _, seq in d.delivered})
    assert o.judged is not None
    assert not any(o.judged.failed(p) or o.judged.proven(p) for p in w.parties)


def test_the_link_records_every_copy_it_made_and_dropped():
    link = Link("x", Impairment(parse_impairment("loss=0.3,dup=0.5,delay=0-1000ms,seed=5")), DelayQueue())
    for i in range(2000):
        link.send(b"d%d" % i, float(i), lambda body, i=i: (i, body))
    assert link.duplicates > 0 and link.drops > 0 and link.max_copies == 2
    assert len(link.records) == 2000 + link.duplicates
    assert len(link.queue) == len(link.records) - link.drops
    assert all(r.t_arrive is None or 0.0 <= r.t_arrive - r.t_sent <= 1.0 for r in link.records)


def test_the_simulated_link_decides_as_the_runners():
    """The same spec, seed, direction and datagrams: the simulator's link makes the very
    decisions ``harness.impair`` makes for ``mcp-impair`` and ``mcp-soak``'s medium."""
    spec = parse_impairment("loss=0.2,dup=0.3,copies=2,reorder=0.3,delay=10-900ms,burst=0.1/0.5,seed=9")
    runner, sim = Impairment(spec), Link("drone1:down", Impairment(spec), DelayQueue())
    for i in range(500):
        data = b"m%d" % (i % 40)  # copies of the same message: the c-th copy's own stream
        want = runner.decide("drone1:down", data, i * 0.05)
        assert sim.send(data, i * 0.05, lambda body: body) == want


def test_a_world_delivers_each_copy_when_its_link_said():
    o = run_schedule(Schedule(seed=5, drones=2, down=BAD, up=BAD), judge=False)
    w = o.world
    due = sorted(round(r.t_arrive * 1e9) for (_, to), link in w.links.items() for r in link.records
                 if r.t_arrive is not None and r.t_arrive <= w.view_end(to))  # by its reader's close
    read = sorted(r.t_ns for v in w.views.values() for r in v if not r.tx)
    assert read == due  # no stalls: every copy read the instant it was due, none lost on the way
    assert any(link.duplicates for link in w.links.values())


def test_a_bad_link_value_is_refused():
    with pytest.raises(ImpairmentError, match="loss"):
        parse_impairment("loss=1.5")
    with pytest.raises(ValueError, match="corrupt is not simulated"):
        Schedule(seed=1, down=parse_impairment("corrupt=0.1"))
    with pytest.raises(ValueError, match="unknown fault"):
        Schedule(seed=1, fault="nope")


def test_a_stalled_party_reads_late_and_its_sends_carry_the_run_delay():
    s = Schedule(seed=11, rto=1.0, stalls=StallParams(count=3, max_len=3.0, span=10.0))
    o = run_schedule(s, judge=False)
    w = o.world
    stalled = {p: win for p, win in w.stalls.items() if win}
    assert stalled, "the seed draws stalls"
    for p, windows in stalled.items():
        for r in w.views[p]:
            t = r.t_ns / 1e9
            assert not any(a + 1e-6 < t < b - 1e-6 for a, b in windows), (p, t, windows)
    # the view of each party is in time order, its own datagrams carry a run delay
    for v in w.views.values():
        assert [r.t_ns for r in v] == sorted(r.t_ns for r in v)
        assert all((r.run_delay is not None) == r.tx for r in v)
        assert all(peek_header(r.data) is not None for r in v)


def test_the_simulator_touches_no_socket_thread_or_clock():
    import ast
    from pathlib import Path

    from mcp_conform import sim
    for path in Path(sim.__file__).parent.glob("*.py"):
        tree = ast.parse(path.read_text())
        names = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
        names |= {(n.module or "").split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
        assert not names & {"socket", "threading", "time", "asyncio", "selectors"}, path.name


@pytest.mark.parametrize("fault", [None, "no-ack", "wrong-seq-ack"])
def test_one_judge_alone_gives_its_verdicts_of_both(fault):
    """``run_schedule(monitor=False)`` / ``(explain=False)`` (test_properties' searches check one
    judge each): the judge that ran gives what it gives beside the other, and ``check`` refuses to
    read the property of the one left out, where it would find nothing."""
    from mcp_conform.sim.search import check

    s = Schedule(seed=7, drones=2, challenge=2, items=2, down=BAD, up=BAD, fault=fault,
                 stalls=StallParams(count=2, max_len=2.0, span=20.0))
    both, mon, exp = run_schedule(s), run_schedule(s, explain=False), run_schedule(s, monitor=False)
    assert (mon.judged.violations, mon.judged.verdicts, mon.judged.vetoed, mon.judged.explained) == (
        both.judged.violations, both.judged.verdicts, both.judged.vetoed, {})
    assert {p: {r: (v.status, v.evidence) for r, v in e.items()} for p, e in exp.judged.explained.items()} == {
        p: {r: (v.status, v.evidence) for r, v in e.items()} for p, e in both.judged.explained.items()}
    assert (exp.judged.violations, exp.judged.verdicts) == ({}, {})
    assert check(mon, ("monitor",)) == check(both, ("monitor",))
    assert check(exp, ("explain",)) == check(both, ("explain",))
    for o, other in ((mon, "explain"), (exp, "monitor")):
        with pytest.raises(ValueError, match=f"check by {other}"):
            check(o, (other,))
