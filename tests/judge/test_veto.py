"""judge.explain's veto over the monitor's MCP-RTX-1/2 failures (``judge/veto.py``, issue 38
item 1): on the simulator's seeds that blamed a correct node the failure is dropped and its
explanation kept; past the record cap it stands; a faulty sender's failure stands."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from mcp_conform.judge import veto as veto_module
from mcp_conform.judge.monitor import Monitor
from mcp_conform.sim.search import replay
from mcp_conform.sim.world import NS
from tests.judge.monitor_faults import FAULTY

SEEDS = Path(__file__).resolve().parents[1] / "sim" / "seeds"
#: seed -> (node, rule) the monitor failed a correct node on, which explain explains away: as
#: each seed's ``vetoed`` says (``tests/sim/test_seeds.py`` replays it)
VETOED = {
    name: (int(v.split()[1]), v.split()[2].rstrip(":"))
    for name in ("monitor-rtx1-starved-drone", "monitor-rtx1-starved-manager", "monitor-rtx2-wrong-source-ack")
    for v in json.loads((SEEDS / f"{name}.json").read_text())["vetoed"][:1]
}
STARVED, STARVED_NODE = "monitor-rtx1-starved-drone", VETOED["monitor-rtx1-starved-drone"][0]


def _monitor_of(name: str, node: int, end_run_delay: bool = False) -> Monitor:
    """The seed's party ``node`` judged in its own view, as ``sim.judges`` does (its run delay
    at the view's end fed too with ``end_run_delay``)."""
    o, _ = replay(SEEDS / f"{name}.json")
    w, s = o.world, o.schedule
    mon = Monitor(rto=s.rto, ack_window=max(0.5, 2 * s.rto), drones=tuple(w.drones),
                  complete=True, party=node, rto_declared=True)
    for r in w.views[node]:
        mon.datagram(r.t_ns, r.src_addr, r.dst_addr, r.data, run_delay=r.run_delay if r.tx else None)
    end = int(w.view_end(node) * NS)
    if end_run_delay:
        mon.run_delay(end, node, w.run_delay_ns[node])
    mon.finish(end)
    return mon


def test_a_stall_after_the_last_datagram_is_known_by_the_run_delay_at_the_views_end() -> None:
    """The seed ``monitor-rtx1-starved-then-closed``: the manager (correct) is stalled while
    End_Mission's retransmission falls due, then reads the ACK and closes, sending nothing: no
    datagram of its carries the stall's run delay (0 at every one), so the ACK is late in
    wall time and MCP-RTX-1 fails. Its run delay at its view's end (``Monitor.run_delay``,
    13.98 s) bounds the stall, and the right ACK is named as what ended it."""
    node = 0
    without = _monitor_of("monitor-rtx1-starved-then-closed", node)
    assert without.verdicts()[node]["MCP-RTX-1"] == "failed" and not without.vetoed
    mon = _monitor_of("monitor-rtx1-starved-then-closed", node, end_run_delay=True)
    assert mon.verdicts()[node]["MCP-RTX-1"] == "passed"
    (x,) = [x for x in mon.vetoed if (x.violation.node, x.violation.rule) == (node, "MCP-RTX-1")]
    assert "End_Mission" in x.violation.actual and "may have ended it" in x.explanation


def test_a_run_delay_at_the_end_excuses_no_silence_it_does_not_cover() -> None:
    """The sample is one more run delay of the node, nothing else: a drone starved in the seed
    ``monitor-rtx1-starved-drone`` whose run delay at the end is what its last datagram carried
    (no stall after it) keeps the verdicts it had without the sample."""
    name, node = STARVED, STARVED_NODE
    w = replay(SEEDS / f"{name}.json")[0].world
    assert w.run_delay_ns[node] == [r.run_delay for r in w.views[node] if r.tx][-1] > 0
    with_end = _monitor_of(name, node, end_run_delay=True)
    plain = _monitor_of(name, node)
    assert with_end.verdicts() == plain.verdicts()
    assert [x.note() for x in with_end.vetoed] == [x.note() for x in plain.vetoed]


@pytest.mark.parametrize("name", sorted(VETOED))
def test_a_correct_nodes_failure_is_vetoed_with_its_explanation(name: str) -> None:
    node, rule = VETOED[name]
    mon = _monitor_of(name, node)
    assert mon.verdicts()[node][rule] == "passed"
    assert not [v for v in mon.violations if (v.node, v.rule) == (node, rule)]
    found = [x for x in mon.vetoed if (x.violation.node, x.violation.rule) == (node, rule)]
    assert found
    for x in found:
        assert x.sender == node and "judge.explain explains the trace" in x.note()
        assert "may have ended it" in x.explanation  # the right ACK that explains the stop, named


def test_past_the_record_cap_the_failure_stands(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(veto_module, "RECORD_CAP", 10)
    mon = _monitor_of(STARVED, STARVED_NODE)
    assert mon.verdicts()[STARVED_NODE]["MCP-RTX-1"] == "failed"
    assert not mon.vetoed and mon.recorder.note is not None


@pytest.mark.parametrize("name", ["rtx2-stops-on-wrong-ack", "rtx2-manager-takes-a-stale-ack",
                                  "rtx2-manager-moves-on-after-a-wrong-ack", "rtx1-gives-up"])
def test_a_faulty_senders_failure_stands(name: str) -> None:
    """Explain keeps RTX-2 here by a give-up at a retry limit or a stop that broke BLK-1
    (``test_explain_beside_monitor``'s KNOWN): no right ACK explains the stop, so no veto."""
    fault = FAULTY[name]
    found = fault.build().judge(complete=fault.complete)
    assert fault.rule in {v.rule for v in found}


def test_mcp_capture_check_gets_the_veto_and_notes_it(tmp_path: Path) -> None:
    """The same starved drone's view written as its own capture (``mcp-soak``'s writer, as
    the simulator's views are) and judged by ``mcp-capture check``'s judge: the monitor's
    failure is dropped from the violations and named in the notes with its explanation."""
    from mcp_conform.judge.judging import Params, judge
    from tests.judge.sim_views import write_view

    o, _ = replay(SEEDS / f"{STARVED}.json")
    s = o.schedule
    path = write_view(tmp_path / f"drone{STARVED_NODE}.mcap", o, STARVED_NODE)
    j = judge(path, Params())
    assert j.params.rto == s.rto
    assert j.verdicts[STARVED_NODE]["MCP-RTX-1"] == "passed"
    assert not [v for v in j.violations if v.rule == "MCP-RTX-1"]
    assert [n for n in j.notes if n.startswith(f"MCP-RTX-1 not failed for node {STARVED_NODE}")]


def test_the_reports_monitor_section_lists_what_was_vetoed() -> None:
    """A live view shows a failure as the traffic comes; the report, written after the
    monitor's finish, must let it be reconciled: the vetoed failure is not among the section's
    violations, and is in its ``vetoed`` list with the explanation (conformance/report.schema.json)."""
    import json

    import jsonschema

    from mcp_conform.judge.run_monitor import RunMonitor, SessionMonitors

    node, rule = VETOED[STARVED]
    run = RunMonitor(rto=0.2, ack_window=0.5, broadcast_id=0xFFFF, node_id=node, node_addr=None)
    run.monitor = _monitor_of(STARVED, node)
    section = run.to_json()
    assert not [v for v in section["violations"] if (v["node"], v["rule"]) == (node, rule)]
    (x,) = [x for x in section["vetoed"] if (x["node"], x["rule"]) == (node, rule)]
    assert x["sender"] == node and "may have ended it" in x["explanation"]
    schema = json.loads((Path(__file__).resolve().parents[2] / "conformance" / "report.schema.json").read_text())
    monitor = {**schema["properties"]["monitor"], "$defs": schema["$defs"]}  # its shapes are $defs
    jsonschema.validate(section, monitor)
    merged = SessionMonitors(rto=0.2, ack_window=0.5, broadcast_id=0xFFFF, node_id=node, node_addr=None)
    merged.parts = {"a": run, "b": run}
    assert len(merged.to_json()["vetoed"]) == 2 * len(section["vetoed"])
