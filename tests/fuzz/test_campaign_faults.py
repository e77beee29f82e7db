"""A campaign under faults of its own (issue 19 items 1 and 6): the node killed in attach
mode, and the campaign interrupted with SIGINT.

Observed before: a node killed with SIGKILL mid-campaign in attach mode gave "confirmed"
MCP-ROB-* findings (its silence replayed on the same dead node); a campaign interrupted
with SIGINT wrote ``"cases": 0, "workers": []`` and ``"error": null`` beside its findings,
exit 2. Now a node lost in attach mode ends the campaign: exit 2, one line naming the node,
summary.json with the counts so far and no finding from the dead node; SIGINT ends it with
exit 130 and summary.json recording the interruption and the counts so far.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.capturing import free_port

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
FAST = ["--rto", "0.2", "--ack-window", "0.25"]
STATUS = ["--status-every", "1"]  # a plain status line each second, the first 1 s in (default 10)
STATUS_JOBS = ["--status-every", "1"]  # the line sums the workers and says how many have judged a case
STATUS_WAIT = 60.0  # s: a loaded host is slower


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


def _fuzz(args: list[str]) -> subprocess.Popen[str]:
    """mcp-fuzz in a subprocess with SIGINT at its default (a test runner may ignore it, and
    an ignored signal stays ignored across exec): coreutils' ``env --default-signal``, which
    execs the command, rather than a ``preexec_fn`` in a pytest worker that may run threads."""
    return subprocess.Popen(["env", "--default-signal=INT", sys.executable, "-m", "mcp_conform.fuzz", *args], cwd=ROOT,
                            env=_env(), text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def _wait_status(proc: subprocess.Popen[str], judging: str = "") -> list[str]:
    """Stdout lines up to the first status line (proof that cases were judged); with
    ``judging`` (``--jobs``), the first that says ``workers judging {judging}``. CI run 23:
    5 s after the start, on a loaded host, the second of two workers had judged none."""
    assert proc.stdout is not None
    lines: list[str] = []
    limit = time.monotonic() + STATUS_WAIT
    while time.monotonic() < limit:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line)
        if " cases " in line and (not judging or f"workers judging {judging}" in line):
            return lines
    proc.kill()
    raise AssertionError("no status line: " + "".join(lines) + (proc.stderr.read() if proc.stderr else ""))


def _finish(proc: subprocess.Popen[str], timeout: float = 90.0) -> tuple[int, str, str]:
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        raise AssertionError(f"mcp-fuzz did not end: {out}\n{err}") from None
    return proc.returncode, out, err


def assert_lost(rc: int, out: str, err: str, out_dir: Path, address: str, why: str) -> dict:
    """A campaign ended by its attached target's loss: exit 2, one line naming ``address`` and
    ``why``, and summary.json saying so (its error that line); the summary."""
    lines = err.strip().splitlines()
    assert rc == 2, f"rc {rc}\n{out}\n{err}"
    assert len(lines) == 1 and lines[0].startswith("mcp-fuzz: error: "), err
    assert address in lines[0] and why in lines[0], err
    summary = json.loads((out_dir / "summary.json").read_text())
    assert summary["node_lost"] is True and summary["error"] == lines[0].removeprefix("mcp-fuzz: error: ")
    return summary


def test_node_killed_in_attach_mode_ends_the_campaign_without_a_finding(tmp_path: Path) -> None:
    """Item 1: SIGKILL to the attached reference drone mid-campaign. Before: the campaign
    ran on to its end against nothing and kept MCP-ROB-* 'hung after ...' as confirmed."""
    from tests.spawned import attached_node

    listen_port = free_port()
    out_dir = tmp_path / "out"
    with attached_node(lambda port: [sys.executable, "-m", "mcp_conform.reference_impl", "drone", "--id", "1", "--bind",
                                     f"127.0.0.1:{port}", "--send-to", f"127.0.0.1:{listen_port}", "--rto", "0.2"],
                       listen_port, cwd=ROOT, env=_env()) as (node, node_port):  # it runs and speaks
        proc = _fuzz(["--target", f"127.0.0.1:{node_port}", "--listen", f"127.0.0.1:{listen_port}",
                      *FAST, *STATUS, "--duration", "120", "--out", str(out_dir)])
        _wait_status(proc)
        node.proc.send_signal(signal.SIGKILL)
        rc, out, err = _finish(proc)
    summary = assert_lost(rc, out, err, out_dir, f"127.0.0.1:{node_port}", "stopped answering")
    assert summary["cases"] > 0 and summary["workers"][0]["cases"] == summary["cases"], summary
    assert summary["duration_s"] < 120, summary  # it ended at the loss, not at --duration
    # the reference drone has no fault: whatever was found, none of it is the dead node's silence
    assert not [d for d in out_dir.glob("finding-*")], summary["findings_by_rule"]
    assert summary["findings"] == 0, summary


@pytest.mark.parametrize("jobs", [1, 2])
def test_sigint_keeps_the_counts_so_far(tmp_path: Path, jobs: int) -> None:
    """Item 6: one SIGINT mid-campaign (embedded reference drone). Before: exit 2 and
    summary.json with "cases": 0, "workers": [] and "error": null."""
    summary = _interrupted([*FAST, *(STATUS if jobs == 1 else STATUS_JOBS), "--duration", "120", "--jobs", str(jobs)],
                           tmp_path / "out", judging=f"{jobs}/{jobs}" if jobs > 1 else "")
    assert summary["interrupted"] is True and "interrupted" in (summary["error"] or ""), summary
    assert summary["cases"] > 0, summary
    assert len(summary["workers"]) == jobs and all(w["cases"] > 0 for w in summary["workers"]), summary
    assert sum(w["cases"] for w in summary["workers"]) == summary["cases"]
    assert summary["duration_s"] < 120, summary


@pytest.mark.nsqd
def test_sigint_ends_an_nsqd_campaign_as_it_ends_an_mcp_one(tmp_path: Path) -> None:
    """Issue 37: SIGINT is every protocol's the same way (the one campaign path of fuzz.cli):
    exit 130, one stderr line, summary.json with the counts so far and ``"interrupted": true``.
    Before, an Nsqd campaign's summary.json was rewritten with an elapsed time of 0."""
    summary = _interrupted(["--protocol", "nsqd", *STATUS, "--duration", "120"], tmp_path / "out")
    assert summary["interrupted"] is True and summary["cases"] > 0 and 0 < summary["elapsed_s"] < 120, summary


def _interrupted(args: list[str], out_dir: Path, judging: str = "") -> dict:
    """mcp-fuzz ``args`` given one SIGINT once it judged cases: exit 130 and one stderr line
    that says so; its summary.json."""
    proc = _fuzz([*args, "--out", str(out_dir)])
    _wait_status(proc, judging)
    proc.send_signal(signal.SIGINT)
    rc, out, err = _finish(proc)
    assert rc == 130, f"rc {rc}\n{out}\n{err}"
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "interrupted after" in lines[0], err
    return json.loads((out_dir / "summary.json").read_text())
