"""The runner under faults (issue 8): a node killed mid-run, bad addresses, spawn failures.

Each test first reproduces what was observed (a dead node passing silence cases, a loss
noticed minutes late and blamed on the next input, a bad address taken for a failing node,
a spawn failure without the node's words) and holds the runner to the contract: the loss
is reported on the case in progress within 3 x rto + 2 s of the death, no silence case
passes after it, no MUST failure is blamed on an input sent after it; setup errors exit 2
with one line; spawn failures quote the node.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest

from tests.forkserver import run_module
from tests.spawned import attached_node

from .fault_helpers import (
    SILENCE_RULES,
    WatchedRun,
    case_line,
    children,
    env,
    kill,
    read_mcap,
    read_report,
)
from .runner_helpers import FAST, ROOT, free_port, reference_node_command

pytestmark = pytest.mark.slow

RTO = 0.2
#: The loss is reported within 3 x --rto + the 2-s liveness window of the death, plus HOST_SLACK
#: for a loaded host's late timers and lines (a fresh-clone CI reported it 2.66 s after, at 2.6;
#: beside a bench, four helpers and the slow tier, load average 13-20 on 2 cores, 3.65 s at 3.6):
#: the bound tells "at once" from the "minutes late" of the bug, not the host's speed.
HOST_SLACK = 3.0


def _budget(rto: float) -> float:
    return 3 * rto + 2.0 + HOST_SLACK


BUDGET = _budget(RTO)


def _after_kill(run: WatchedRun, doc: dict, t_kill: float, t_kill_ns: int, budget: float = BUDGET) -> None:
    """No case that ended after the death passed a silence verdict or failed a MUST; the
    loss was reported (an ERROR line naming it) within the budget."""
    later = [c for c in doc["cases"] if (c["capture"]["end_ns"] or 0) > t_kill_ns + 20_000_000]
    assert later, run.text()
    # a robustness case already under way when the node died (proven live before its first
    # input; the kill lands after the watched line, which a loaded host prints late) blames
    # the death on its input: in attach mode no process shows it came from elsewhere
    bad = [c for c in later
           if (c["outcome"] == "failed" and not ((c["capture"]["start_ns"] or 0) < t_kill_ns
                                                 and (c.get("failed_rule") or "").startswith("MCP-ROB-")))
           or (c["outcome"] == "passed" and SILENCE_RULES & set(c["rules"]))]
    assert not bad, f"verdicts after the death: {bad}\n{run.text()}"
    errors = [(ts, ln) for ts, ln in run.case_lines_after(t_kill) if ln.startswith("ERROR")]
    assert errors, run.text()
    ts, line = errors[0]
    print(f"loss reported {ts - t_kill:.2f} s after the death (budget {budget:g} s): {line}")
    assert ts - t_kill <= budget, f"loss reported {ts - t_kill:.2f} s after the death: {line}\n{run.text()}"
    # the first error after the death: a case that errors at once ("target lost") has no
    # capture window of its own (start_ns and end_ns None), as when the case in progress was a
    # robustness case that blamed the death on its input (above)
    first = next(c for c in doc["cases"] if c["outcome"] == "error"
                 and (c["capture"]["end_ns"] is None or c["capture"]["end_ns"] > t_kill_ns + 20_000_000))
    # the case in progress, or the first case run again after the silence cases' batch the
    # node died in was thrown away (conformance.schedule): "target lost" in an earlier case
    assert ("node lost during this case" in (first["reason"] or "")
            or "node not live" in (first["reason"] or "") or "target lost" in (first["reason"] or "")), first


@pytest.mark.parametrize("kill_after", [
    "SEQ/test_initial_sequence_number_is_recorded",      # ACK-1 in progress: commands unanswered
    "ACK/test_ack_is_addressed_back_to_the_sender",       # ACK-4: a silence window
    "PAY/test_sender_payload_rules[MCP-PAY-6]",            # ROB-1 next: its inputs to a dead node
])
def test_attach_node_killed_mid_run(tmp_path, kill_after):
    """Observed: ACK-4/5/6 passed against a dead node; ROB-1 failed on the empty datagram
    sent to a node already dead; the loss came minutes late."""
    _attach_kill(tmp_path, kill_after, RTO, FAST)


def test_attach_node_killed_mid_run_at_the_descriptions_timings(tmp_path):
    """The same at the description's 5 s timeout (node and runner alike, the runner's default
    --ack-window): the loss is reported within 3 x 5 + 2 s of the death, on the case in
    progress (here MCP-ACK-1, whose commands the dead node never answers)."""
    _attach_kill(tmp_path, "SEQ/test_initial_sequence_number_is_recorded", 5.0, [], wait=150)


def _reference_node(rto: float, listen_port: int):
    """The reference drone's command line (attach mode, its own vehicle) for a port."""
    import shlex

    return lambda port: shlex.split(reference_node_command(rto).replace("{id}", "1")
                                    .replace("{target_host}:{target_port}", f"127.0.0.1:{port}")
                                    .replace("{listen_host}:{listen_port}", f"127.0.0.1:{listen_port}")
                                    .replace("--mavlink {mavlink} ", ""))


def _attach_kill(tmp_path, kill_after: str, rto: float, timing: list[str], wait: float = 60) -> None:
    budget = _budget(rto)
    listen_port = free_port()
    js = tmp_path / "r.json"
    # not waited for (the runner's startup waits for its Mission_Ready); its stderr in the failure
    with attached_node(_reference_node(rto, listen_port), None, env=env(), cwd=ROOT) as (node, node_port):
        run = WatchedRun(["--target", f"127.0.0.1:{node_port}", "--listen", f"127.0.0.1:{listen_port}",
                          *timing, "--json", str(js)])
        try:
            run.wait_line(case_line(kill_after), wait)
        except AssertionError as exc:
            run.proc.kill()
            run.finish()
            raise AssertionError(f"{exc}\nthe node: {node.explain()}") from None
        t_kill_ns = time.time_ns()
        t_kill = kill(node.pid)
        rc = run.finish()
    doc = read_report(js)
    assert rc == 1, run.text()
    _after_kill(run, doc, t_kill, t_kill_ns, budget)
    # attach: every case after the one in progress is an error at once
    later = [c for c in doc["cases"] if (c["capture"]["start_ns"] or 0) > t_kill_ns]
    assert all(c["outcome"] == "error" for c in later[1:]), later


def test_spawn_node_killed_mid_run_is_restarted(tmp_path):
    """Spawn mode: the exit is noticed at once, the case in progress is an error naming the
    signal, the node is restarted and the rest of the suite passes."""
    _spawn_kill(tmp_path, "ACK/test_every_command_type_is_acked", RTO, FAST, [])


def test_spawn_node_killed_mid_run_at_the_descriptions_timings(tmp_path):
    """The same at the description's 5 s timeout (node and runner alike): the startup phase
    alone takes ~30 s of withheld ACKs, so only the startup observation and the ACK cases
    run; the node dies during MCP-ACK-1, is restarted, and MCP-ACK-2 and the end pass."""
    _spawn_kill(tmp_path, "SEQ/test_initial_sequence_number_is_recorded", 5.0, [],
                ["--select", "MCP-SEQ-4", "MCP-ACK-1", "MCP-ACK-2"], wait=150)


class _SlowToSayProcess:
    """A spawned node whose last words take ``delay`` s to collect once it is dead (its output
    threads joined, as ``harness.procs.ManagedProcess.evidence`` does after a death): the
    watcher's declaration of the death takes that long."""

    def __init__(self, delay: float) -> None:
        self.returncode: int | None = None
        self.delay = delay

    def alive(self) -> bool:
        return self.returncode is None

    def evidence(self) -> list[str]:
        if self.returncode is not None:
            time.sleep(self.delay)
        return [f"node exit: {self.returncode}"]


def test_a_death_in_a_cases_last_exchange_is_named_with_its_exit_not_as_silence():
    """CI once reported this module's description-timings kill as "node lost during this case:
    it answers no liveness probe either": the node died while MCP-ACK-1's case awaited the ACK
    of its last command; the case's wait saw the process gone (``driver.alive``) and returned
    the exchange unanswered while the watcher was still declaring the death (its evidence waits
    for the node's last output), and the case's proof of life then met the declared loss and
    called it silence. Here a node ACKs the case's commands and is SIGKILLed on the last one;
    the watcher runs and takes 0.5 s to declare. The case (MCP-ACK-1's, as the runner runs it)
    must end in ``NodeLost`` naming the signal. Before the fix: SilenceUnproven "it answers no
    liveness probe either", every run."""
    import socket
    import threading
    from types import SimpleNamespace

    from mcp_conform.conformance.cases.test_ack import _COMMANDS
    from mcp_conform.conformance.cases.test_ack import test_every_command_type_is_acked as case
    from mcp_conform.conformance.drone_case import CaseContext
    from mcp_conform.harness.driver import TargetDriver
    from mcp_conform.harness.errors import NodeLost
    from mcp_conform.harness.liveness import Liveness
    from mcp_conform.spec.codec import Action, Message, encode, peek_header

    rto, node_id = 0.2, 1
    node_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # held open: nothing else binds it
    node_sock.bind(("127.0.0.1", 0))
    node_sock.settimeout(0.1)
    drv = TargetDriver(node_sock.getsockname(), ("127.0.0.1", 0), our_id=0)
    drv.open()
    proc = _SlowToSayProcess(0.5)
    drv.alive = proc.alive
    watch = Liveness(drv, rto, lambda: node_id)
    watch.reset(proc)
    watch.enable()
    stop = threading.Event()

    def node() -> None:
        """ACK each command; SIGKILLed as the case's last one arrives, unanswered."""
        n = 0
        while not stop.is_set() and proc.alive():
            try:
                data, addr = node_sock.recvfrom(65535)
            except TimeoutError:
                continue
            hdr = peek_header(data)
            if hdr is None or hdr[3] == Action.ACK:
                continue
            n += 1
            if n == len(_COMMANDS):
                proc.returncode = -9
                return
            node_sock.sendto(encode(Message(hdr[1], node_id, 100 + n, Action.ACK, hdr[2])), addr)

    session = SimpleNamespace(driver=drv, rto=rto, ack_window=rto, cfg=SimpleNamespace(broadcast_id=0xFFFF),
                              target_id=node_id, node=proc, alive=proc.alive, node_evidence=proc.evidence,
                              declare_not_live=lambda why: None, liveness=watch)
    runner = threading.Thread(target=node, daemon=True)
    try:
        watch.start()
        runner.start()
        ctx = CaseContext(session, "ACK/test_every_command_type_is_acked", ("MCP-ACK-1",))
        with pytest.raises(NodeLost) as info:
            case(ctx)
    finally:
        stop.set()
        runner.join(timeout=2.0)
        watch.close()
        drv.close()
        node_sock.close()
    assert "killed by signal SIGKILL" in info.value.reason, info.value.reason
    assert info.value.process_exited and "node exit: -9" in info.value.evidence


def test_a_wait_that_sees_the_process_gone_names_the_death_before_the_watcher_looks():
    """The harness half: a wait (``TargetDriver.wait_for``, behind every exchange) that finds
    the process gone raises ``NodeLost`` with its exit, though the watcher has not looked yet
    (never ticked here). Before the fix it returned None, an unanswered exchange: the case went
    on with a dead node taken for a silent one."""
    import socket

    from mcp_conform.harness.driver import TargetDriver
    from mcp_conform.harness.errors import NodeLost
    from mcp_conform.harness.liveness import Liveness
    from mcp_conform.spec.codec import Action

    node_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # held open: nothing else binds it
    node_sock.bind(("127.0.0.1", 0))
    drv = TargetDriver(node_sock.getsockname(), ("127.0.0.1", 0), our_id=0)
    drv.open()
    proc = _SlowToSayProcess(0.0)
    drv.alive = proc.alive
    watch = Liveness(drv, 0.2, lambda: 1)
    watch.reset(proc)
    watch.enable()
    try:
        sent = drv.send(Action.WP_OFF, None, 1)
        proc.returncode = -9
        with pytest.raises(NodeLost) as info:
            drv.exchange(sent, rto=0.2, copies=3)
    finally:
        watch.close()
        drv.close()
        node_sock.close()
    assert "killed by signal SIGKILL" in info.value.reason and info.value.exchange is not None


def _spawn_kill(tmp_path, kill_after: str, rto: float, timing: list[str], select: list[str],
                wait: float = 60) -> None:
    budget = _budget(rto)
    js = tmp_path / "r.json"
    # on a loaded host the kill may land between two cases: try again (3 tries all missed once
    # beside 9 busy workers: the cases around the batch last milliseconds at --rto 0.2)
    for attempt in range(ATTEMPTS := 5):
        run = WatchedRun(["--spawn", reference_node_command(rto), "--mavlink", *timing, *select,
                          "--json", str(js)])
        run.wait_line(case_line(kill_after), wait)
        pids = children(run.proc.pid, "reference_impl")
        assert len(pids) == 1, pids
        t_kill_ns = time.time_ns()
        t_kill = kill(pids[0])
        rc = run.finish()
        doc = read_report(js)
        if rc == 0 and not [c for c in doc["cases"] if c["outcome"] != "passed" and c["outcome"] != "skipped"
                            and c["outcome"] != "info"] and attempt < ATTEMPTS - 1:
            print(f"attempt {attempt + 1}: the node died between two cases (restarted, nothing lost); again")
            continue
        break
    assert rc == 1, run.text()
    errors = [c for c in doc["cases"] if c["outcome"] == "error"]
    assert len(errors) == 1, run.text()
    assert "node lost during this case" in errors[0]["reason"], errors
    assert "SIGKILL" in errors[0]["reason"], errors
    assert not [c for c in doc["cases"] if c["outcome"] == "failed"], run.text()
    ts, line = next((ts, ln) for ts, ln in run.case_lines_after(t_kill) if ln.startswith("ERROR"))
    print(f"loss reported {ts - t_kill:.2f} s after the death (budget {budget:g} s): {line}")
    assert ts - t_kill <= budget, run.text()
    assert [c for c in doc["cases"] if (c["capture"]["start_ns"] or 0) > t_kill_ns and c["outcome"] == "passed"]


# ---------------------------------------------------------------------- setup errors
def _conform(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    return run_module("conformance", list(args), cwd=ROOT, env=env(), timeout=timeout)


@pytest.mark.parametrize("args,words", [
    (["--target", "no-such-host.invalid:7890"], "cannot resolve host"),
    (["--target", "127.0.0.1:0"], "port 0"),
    (["--target", "127.0.0.1:9", "--listen", "203.0.113.7:0"], "cannot listen on 203.0.113.7"),
    (["--target", "127.0.0.1:{port}", "--listen", "127.0.0.1:0", "--timeout", "3"], "--timeout of 3 s"),
    (["--target", "127.0.0.1:{port}", "--listen", "127.0.0.1:0", *FAST], "target never answered"),
])
def test_bad_addresses_are_setup_errors(tmp_path, args, words):
    """Observed: exit 1 after ~16 s with 44 cases in error; --timeout gave 44 'run deadline
    exceeded' errors. Now: exit 2, one line on stderr, no case run."""
    args = [a.replace("{port}", str(free_port())) for a in args]
    js = tmp_path / "r.json"
    t0 = time.monotonic()
    proc = _conform(*args, "--json", str(js))
    took = time.monotonic() - t0
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0], proc.stderr
    assert "Traceback" not in proc.stdout + proc.stderr
    doc = read_report(js)
    assert doc["cases"] == [] and words in doc["error"]
    assert took < 30, took


# ---------------------------------------------------------------------- spawn failures
@pytest.mark.parametrize("spawn,words,extra", [
    ('sh -c "echo starting; echo oops >&2; exit 3"', ["starting", "oops", "exited with code 3"], []),
    ("python my_drone.py --id {id}", ["can't open file", "exited with code 2"], []),
    ('sh -c "echo hello; exec sleep 30"', ["hello", "no Mission_Ready within the run's --timeout"], ["--timeout", "6"]),
    ('sh -c "echo bye; kill -9 $$"', ["bye", "killed by signal SIGKILL"], ["--mavlink"]),
])
def test_spawn_failures_quote_the_node(tmp_path, spawn, words, extra):
    """Observed: 'exited with code 3' without the node's output; Python's "can't open file"
    lost; with --mavlink a node that exits at once reported after ~26 s."""
    js = tmp_path / "r.json"
    t0 = time.monotonic()
    proc = _conform("--spawn", spawn, *FAST, *extra, "--json", str(js))
    took = time.monotonic() - t0
    assert proc.returncode == 2, proc.stdout + proc.stderr
    for w in words:
        assert w in proc.stderr, proc.stderr
    assert "command: " in proc.stderr
    doc = read_report(js)
    node = doc["node"]
    assert node["command"][0] in ("sh", "python")
    quoted = " ".join([doc["error"], node["exit"] or "", *node["stdout"], *node["stderr"]])
    for w in words:
        assert w in quoted, doc
    if "--mavlink" in extra:  # was: reported after the 20 s wait for the vehicle's connection
        waited = doc["summary"]["duration_s"]
        assert waited < 10, f"a node that exits at once is reported as it exits (run {waited:.1f} s, {took:.1f} s in all)"


def test_closed_stdout_ends_quietly(tmp_path):
    """Observed: `mcp-conform | head -3` aborted after 3 cases with a traceback and
    'internal error' in the JSON; `--list | head -1` printed an INTERNALERROR."""
    js = tmp_path / "r.json"
    py = sys.executable
    script = (f"{py} -m mcp_conform.conformance --select MCP-ACK-2 MCP-ACK-3 MCP-ACK-4 MCP-HDR --json {js} | head -3; "
              f"echo rc=${{PIPESTATUS[0]}}; {py} -m mcp_conform.conformance --list | head -1; echo rc=${{PIPESTATUS[0]}}")
    proc = subprocess.run(["bash", "-c", script], cwd=ROOT, env=env(), capture_output=True, text=True, timeout=120)
    out = proc.stdout.splitlines()
    assert out[3] in ("rc=0", "rc=1") and out[-1] == "rc=0", proc.stdout + proc.stderr
    assert out[4].startswith("BLK/"), proc.stdout
    assert "Traceback" not in proc.stderr and "INTERNALERROR" not in proc.stderr, proc.stderr
    doc = read_report(js)
    assert doc["error"] is None and len(doc["cases"]) >= 6 and doc["summary"]["error"] == 0, doc


# ---------------------------------------------------------------------- signals, orphans
@pytest.fixture(scope="module")
def attach_node():
    """One reference node for many short runs (attach mode: no node to start per run)."""
    listen_port = free_port()
    with attached_node(_reference_node(RTO, listen_port), listen_port, env=env(), cwd=ROOT) as (_, node_port):
        yield node_port, listen_port


SIGNAL_RUNS = int(os.environ.get("MCP_SIGNAL_RUNS", "5"))


@pytest.mark.parametrize("count", [2, 3, 10])
@pytest.mark.parametrize("signame", ["SIGINT", "SIGTERM"])
def test_signals_in_quick_succession_leave_valid_reports(tmp_path, attach_node, signame, count):
    """Observed: two SIGINTs 0.1 s apart gave a traceback and no JSON; two SIGTERMs no JSON
    and a truncated MCAP. ``SIGNAL_RUNS`` runs (5 in CI: 30 over the six signal and count
    combinations, 0.4 CPU s each; ``MCP_SIGNAL_RUNS=20`` as issue 8 measured), each signalled
    ``count`` times 5 ms apart at a moment drawn (seeded) from its first 2 s once its code runs
    (before that the interpreter's default handlers are in place): imports, startup, cases
    alike."""
    import random
    import signal

    node_port, listen_port = attach_node
    sig = getattr(signal, signame)
    rnd = random.Random(f"{signame}{count}")
    for rep in range(SIGNAL_RUNS):
        js, cap = tmp_path / f"r{rep}.json", tmp_path / f"r{rep}.mcap"
        proc = subprocess.Popen(
            [sys.executable, "-m", "mcp_conform.conformance", "--target", f"127.0.0.1:{node_port}",
             "--listen", f"127.0.0.1:{listen_port}", *FAST, "--select", "MCP-ACK", "MCP-ROB-1",
             "--json", str(js), "--capture", str(cap)],
            cwd=ROOT, env=env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        _handlers_installed(proc.pid)
        at = rnd.uniform(0.0, 2.0)
        time.sleep(at)
        for _ in range(count):
            if proc.poll() is not None:
                break
            proc.send_signal(sig)
            time.sleep(0.005)
        _, err = proc.communicate(timeout=60)
        what = f"run {rep}, {count} x {signame} at {at:.2f} s: exit {proc.returncode}\n{err}"
        assert proc.returncode == 128 + sig, what  # the one grammar: 130 for SIGINT, 143 for SIGTERM
        assert "Traceback" not in err, what
        doc = read_report(js)
        assert doc["error"].startswith("interrupted"), what
        if doc["cases"] or cap.exists():
            read_mcap(cap)


def _handlers_installed(pid: int, timeout: float = 10.0) -> None:
    """Wait until the process catches SIGINT and SIGTERM (SigCgt in /proc/PID/status)."""
    import signal

    want = (1 << (signal.SIGINT - 1)) | (1 << (signal.SIGTERM - 1))
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            with open(f"/proc/{pid}/status") as f:
                caught = next(int(ln.split()[1], 16) for ln in f if ln.startswith("SigCgt:"))
        except (OSError, StopIteration):
            return
        if caught & want == want:
            return
        time.sleep(0.005)


def test_kill_9_of_the_runner_leaves_no_process(tmp_path):
    """Observed: the spawned or embedded node (and the vehicle) lived on, re-parented to
    init, retransmitting for ~80 minutes. The run's processes are found by an environment
    mark they all inherit; a node that is a grandchild (``sh -c '...; true'``) is included."""
    import signal

    from .fault_helpers import marked_pids, new_mark
    from .runner_helpers import sample_node_command

    for args in ([],  # the embedded reference node with its vehicle
                 ["--mavlink", "--spawn", f"sh -c '{sample_node_command(rto=RTO)}; true'", *FAST]):
        mark = new_mark()
        run = WatchedRun(args, mark=mark)
        run.wait_line(lambda ln: ln.startswith("PASSED"), 60)
        pids = marked_pids(mark)
        assert len(pids) >= 3, pids  # runner, reaper, node (and sh)
        kill(run.proc.pid, signal.SIGKILL)
        run.finish()
        time.sleep(2.0)
        assert marked_pids(mark) == [], (args, marked_pids(mark))
