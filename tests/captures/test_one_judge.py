"""One judge (issue 18 item 6): ``mcp-capture check`` of an ``mcp-conform`` capture gives the
run's live monitor verdicts, rule by rule, for every node — by default and with
``--complete`` — on the reference node and the reference manager, and on faulty managers of
our own. (The faulty drones, each with its own fault, are held to it in
tests/conformance/test_mutants.py, in the run that catches their fault.)"""

from __future__ import annotations

import pytest

from judge.judging import Params, judge
from tests.conformance.runner_helpers import (
    FAST,
    run_conform,
    sample_manager_command,
    verdict_differences,
)

pytestmark = pytest.mark.slow

NODES = [
    ("reference", ()),                                      # the embedded reference node
    ("manager-reference", ("--role", "manager")),
    ("manager-ack-ack", ("--role", "manager", "--spawn", sample_manager_command("--fault", "ack-ack"), *FAST)),
    ("manager-after-end",
     ("--role", "manager", "--spawn", sample_manager_command("--fault", "after-end"), *FAST)),
    ("manager-no-ready-ack",
     ("--role", "manager", "--spawn", sample_manager_command("--fault", "no-ready-ack"), *FAST)),
]
#: The manager role's run monitor judges the whole run as a lossy trace (the cases restart the
#: manager and replay missions), so ``--complete`` is not that run's judgement.
LOSSY = {"manager-reference", "manager-ack-ack", "manager-after-end", "manager-no-ready-ack"}


@pytest.mark.parametrize(("label", "args"), NODES, ids=[n for n, _ in NODES])
def test_check_of_the_runs_capture_gives_the_live_verdicts(tmp_path, label, args):
    cap = tmp_path / "run.mcap"
    res = run_conform(*args, "--capture", str(cap))
    live = res.report["monitor"]["rules"]
    assert live, res.explain()
    for complete in (False,) if label in LOSSY else (False, True):
        j = judge(cap, Params(complete=complete))
        assert verdict_differences(live, j.verdicts) == [], (complete, res.explain())
        live_violations = sorted((v["rule"], v["node"]) for v in res.report["monitor"]["violations"])
        assert sorted((v.rule, v.node) for v in j.violations) == live_violations
    if label == "reference":  # the reference node: a clean monitor section, most rules judged
        mon = res.report["monitor"]
        assert mon["complete"] and mon["datagrams"] > 50 and mon["violations"] == []
        assert [n["id"] for n in mon["nodes"]] == [1]
        assert sum(v == "passed" for v in mon["rules"]["1"].values()) >= 15
    if label == "manager-no-ready-ack":
        # the case fails MCP-ACK-1 on its own exchanges; a lossy trace proves no absence, so the
        # run's monitor and the check of its capture leave it unjudged, never "passed"
        assert res.rc == 1 and res.rules["MCP-ACK-1"] == "failed", res.explain()
        assert live["0"]["MCP-ACK-1"] == j.verdicts[0]["MCP-ACK-1"] == "not_observed", live["0"]
    if label == "manager-after-end":
        # faults the monitor proves from traffic: they show in both
        assert any(v for t in live.values() for v in t.values() if v in ("failed", "warned"))
