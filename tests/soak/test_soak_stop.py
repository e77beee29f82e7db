"""``mcp-soak`` ends what it started and says how (issue 38 item 6): each node's ending is
named (an exit 0 is an ending, not "did not end"), and SIGTERM or SIGINT mid-mission ends the
manager and the drones (none left behind with parent 1) and writes the summary and ``--json``
with what it has. Missions side by side (``--jobs``) come back in mission order."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from mcp_conform.soak.campaign import Stop, run_missions
from mcp_conform.soak.cli import main
from mcp_conform.soak.mission import MissionResult

ROOT = Path(__file__).resolve().parents[2]


def _stat(pid: int) -> tuple[int, str, int] | None:
    """(ppid, state, start time) of ``pid`` from /proc, None when it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2:].split()
    return int(fields[1]), fields[0], int(fields[19])


def _descendants(pid: int) -> dict[int, int]:
    """Every process below ``pid`` now: pid -> its start time (to tell a reused pid)."""
    parents: dict[int, tuple[int, int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            st = _stat(int(entry.name))
            if st is not None:
                parents[int(entry.name)] = (st[0], st[2])
    out: dict[int, int] = {}
    frontier = [pid]
    while frontier:
        p = frontier.pop()
        for child, (ppid, start) in parents.items():
            if ppid == p and child not in out:
                out[child] = start
                frontier.append(child)
    return out


def _still_there(pid: int, start: int) -> bool:
    st = _stat(pid)
    return st is not None and st[2] == start and st[1] != "Z"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="process trees from /proc are Linux's")
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_a_signal_mid_mission_ends_every_node_and_writes_the_json(sig, tmp_path) -> None:
    """The reference manager and three drones (``--linger 600``: left alone they outlive the
    soak by ten minutes), mid-mission: the soak's whole process tree is gone after it exits,
    and its ``--json`` holds the interrupted mission with how each node ended."""
    out = tmp_path / "soak.json"
    proc = subprocess.Popen([sys.executable, "-m", "mcp_conform.soak", "--missions", "3", "--out", str(tmp_path / "out"),
                             "--json", str(out), "--impair", "loss=0.3,delay=0-50ms"], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    tree: dict[int, int] = {}
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and proc.poll() is None:  # the manager and its drones
            tree.update(_descendants(proc.pid))
            if len(tree) >= 4:
                break
            time.sleep(0.05)
        assert len(tree) >= 4, f"the soak did not start its nodes: {tree}"
        time.sleep(0.5)  # mid-mission: a mission at these settings takes seconds
        tree.update(_descendants(proc.pid))
        proc.send_signal(sig)
        text, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    assert proc.returncode == 128 + sig, text
    left = {p for p, start in tree.items() if _still_there(p, start)}
    assert not left, f"left running: {left}"
    doc = json.loads(out.read_text())
    assert doc["interrupted"] == sig.name and doc["planned"] == 3
    last = doc["results"][-1]
    assert last["outcome"] == "interrupted" and not last["ok"]
    assert any(sig.name in r for r in last["reasons"])
    assert set(last["ended"]) == {"manager", "drone1", "drone2", "drone3"}
    assert all(e["how"] in ("stopped", "killed", "exited") for e in last["ended"].values())
    assert f"stopped by {sig.name}" in text


@pytest.mark.parametrize(("drone", "code"), [("{python} -c pass", 0), ("{python} -c 'raise SystemExit(3)'", 3)])
def test_a_drone_that_exits_is_named_with_its_code(drone, code, tmp_path, capsys) -> None:
    """A drone that exits at once, with 0 or not: the mission (which cannot complete) names it
    ``exited`` with its code; a code other than 0 is a reason of its own. The mission's 6 s:
    an interpreter that starts and exits took over 3 s beside the quick suite's six workers
    (the drone, still starting, was stopped by the soak: 'ended by signal 15')."""
    out = tmp_path / "soak.json"
    rc = main(["--missions", "1", "--drones", "1", "--mission-timeout", "6", "--drone", drone,
               "--out", str(tmp_path / "out"), "--json", str(out), "--impair", "seed=0"])
    assert rc == 1
    r = json.loads(out.read_text())["results"][0]
    assert r["ended"]["drone1"]["how"] == "exited" and r["ended"]["drone1"]["code"] == code
    assert r["ended"]["drone1"]["at_s"] < 6
    assert r["ended"]["manager"]["how"] in ("stopped", "killed")  # it never ended by itself
    assert any("did not end within 6 s" in x for x in r["reasons"])
    assert any("drone1 exited with 3" in x for x in r["reasons"]) == (code == 3)
    assert f"drone1 exited with {code} at" in capsys.readouterr().out


def _fake(durations: dict[int, float], log: list[str], fail: frozenset[int] = frozenset()):
    """A mission that takes ``durations[k]`` seconds (or until stopped) and logs its start and
    end: the campaign's scheduling, without the nodes."""
    def run(k: int, seed: int, challenge: int, stop: Stop) -> MissionResult:
        log.append(f"start {k}")
        stop.wait(durations[k])
        log.append(f"end {k}")
        r = MissionResult(k, seed, challenge, "seed=0", ok=k not in fail and not stop.is_set())
        r.outcome = "interrupted" if stop.is_set() else ("complete" if r.ok else "failed")
        return r
    return run


def test_missions_side_by_side_come_back_in_mission_order() -> None:
    log: list[str] = []
    plan = [(k, 100 + k, 1 + k % 3) for k in range(4)]
    got = run_missions(plan, _fake({0: 0.6, 1: 0.4, 2: 0.2, 3: 0.0}, log), 4, Stop())
    assert [(r.index, r.seed, r.challenge) for r in got] == plan
    assert log[:4] == ["start 0", "start 1", "start 2", "start 3"]  # all at once
    assert log.index("end 3") < log.index("end 0")  # ended out of order, merged in order


def test_no_more_than_jobs_run_at_once_and_fail_fast_starts_no_more() -> None:
    log: list[str] = []
    got = run_missions([(k, k, 1) for k in range(6)], _fake(dict.fromkeys(range(6), 0.05), log,
                       fail=frozenset({1})), 2, Stop(), fail_fast=True)
    running, most = 0, 0
    for line in log:
        running += 1 if line.startswith("start") else -1
        most = max(most, running)
    assert most == 2
    assert [r.index for r in got] in ([0, 1], [0, 1, 2])  # 2 may have started beside 1
    assert not got[1].ok


def test_a_stop_interrupts_the_running_missions_and_starts_no_more() -> None:
    log: list[str] = []
    stop = Stop()
    threading.Timer(0.2, stop.request, ("SIGTERM",)).start()
    got = run_missions([(k, k, 1) for k in range(5)], _fake(dict.fromkeys(range(5), 30.0), log), 2, stop)
    assert [r.outcome for r in got] == ["interrupted", "interrupted"] and stop.why == "SIGTERM"
    assert sorted(log) == ["end 0", "end 1", "start 0", "start 1"]


@pytest.mark.slow
def test_jobs_give_the_serial_missions(tmp_path) -> None:
    """Three reference missions side by side and one after another: the same missions (seed,
    challenge, outcome), in mission order. One drone a mission (what --jobs orders is missions;
    the default three drones started 24 interpreters, 8 CPU s, for the same check: 12 now)."""
    docs = []
    for jobs in ("1", "3"):
        out = tmp_path / f"jobs{jobs}.json"
        assert main(["--missions", "3", "--jobs", jobs, "--seed", "40", "--drones", "1", "--impair", "loss=0.2,dup=0.1",
                     "--out", str(tmp_path / jobs), "--json", str(out), "--no-strict"]) == 0
        docs.append(json.loads(out.read_text()))
    serial, side = ([(r["index"], r["seed"], r["challenge"], r["outcome"]) for r in d["results"]] for d in docs)
    assert serial == side == [(0, 40, 1, "complete"), (1, 41, 2, "complete"), (2, 42, 3, "complete")]
    assert docs[1]["jobs"] == 3


def test_a_node_that_cannot_start_is_named_not_a_traceback(tmp_path) -> None:
    out = tmp_path / "soak.json"
    rc = main(["--missions", "1", "--drones", "1", "--drone", "/no/such/drone --id {id}",
               "--out", str(tmp_path / "out"), "--json", str(out), "--impair", "seed=0"])
    assert rc == 1
    r = json.loads(out.read_text())["results"][0]
    assert r["ended"]["drone1"]["how"] == "not started" and "/no/such/drone" in r["ended"]["drone1"]["detail"]
    assert r["ended"]["manager"]["how"] in ("stopped", "killed")
    assert any("drone1 could not start" in x for x in r["reasons"])
