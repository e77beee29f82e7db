"""Blame only where the input makes the difference (issue 36 item 2): against Nsqd backends
that misbehave whatever they are sent (tests/fuzz/servers/misbehaving_backend.py), a campaign
reports the target's behaviour under the rule mcp-conform names for it (NSQD-MSG-1 for a
stream that trickles, NSQD-FRM-1 for frames whose length is not in network order), with no
input blamed, replayable with no input; and it ends within its ``--duration`` plus the grace
it states (the elapsed time printed, bounded generously: a loaded host is slow, not wrong)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from mcp_conform.fuzz.budget import GRACE_S
from tests.forkserver import run_module

pytestmark = [pytest.mark.slow, pytest.mark.nsqd]

ROOT = Path(__file__).resolve().parents[2]
DURATION = 12.0


def _spawn(mode: str) -> str:
    return (f"{sys.executable} -m tests.fuzz.servers.misbehaving_backend --bind {{target_host}}:{{target_port}} "
            f"--mode {mode} --lifetime 120")


def _fuzz(*args: str) -> subprocess.CompletedProcess[str]:
    """``mcp-fuzz --protocol nsqd ARGS`` in its own process: a child of the tests' fork server
    (tests/forkserver.py), the modules below the fuzzer imported once, not a fresh interpreter's
    ~0.8 CPU s of imports per run (hypothesis, the judge, pymavlink's dialects)."""
    return run_module("mcp_conform.fuzz", ["--protocol", "nsqd", *args], timeout=DURATION + GRACE_S + 120, cwd=ROOT)


@pytest.mark.parametrize("mode,rule", [("slow", "NSQD-MSG-1"), ("bad-frames", "NSQD-FRM-1")])
def test_a_backend_that_misbehaves_whatever_it_is_sent_is_its_own_finding(tmp_path, mode, rule):
    run = _fuzz("--spawn", _spawn(mode), "--duration", f"{DURATION:g}", "--out", str(tmp_path))
    out = run.stdout + run.stderr
    print(out)
    summary = json.loads((tmp_path / "summary.json").read_text())
    print(f"{mode}: elapsed {summary['elapsed_s']} s for --duration {DURATION:g} (grace {summary['grace_s']} s), "
          f"triage {summary['triage_s']} s")
    assert run.returncode == 1, out
    assert [(f["rule"], f["no_input"]) for f in summary["findings"]] == [(rule, True)], summary["findings"]
    doc = json.loads((tmp_path / "finding-1" / "finding.json").read_text())
    assert doc["writes"] == [] and doc["no_input"] and "no input blamed" in doc["note"], doc
    assert f"grace {GRACE_S:g} s" in out and "triage" in out, out
    assert summary["elapsed_s"] <= DURATION + GRACE_S, summary
    replay = _fuzz("--replay", str(tmp_path / "finding-1"), "--spawn", _spawn(mode))
    assert replay.returncode == 1 and "with no input" in replay.stdout, replay.stdout + replay.stderr


def test_the_reference_backend_gives_no_finding_and_keeps_the_bound(tmp_path):
    """The baseline of a correct backend is clean: nothing reported, and the bound holds."""
    run = _fuzz("--duration", "6", "--out", str(tmp_path))
    summary = json.loads((tmp_path / "summary.json").read_text())
    print(run.stdout, f"elapsed {summary['elapsed_s']} s for --duration 6")
    assert run.returncode == 0 and summary["findings"] == [], run.stdout + run.stderr
    assert summary["elapsed_s"] <= 6 + GRACE_S, summary


def test_a_crash_that_replays_once_then_not_is_named_environment_dependent(tmp_path):
    """Seen by the campaign, reproduced by one replay of triage, then by none of the confirming
    replays (misbehaving_backend --mode flaky-crash): no finding, but named in the summary and
    on the last lines, with why, as MCP's campaign names one (``fuzz.environment``)."""
    spawn = (f"{sys.executable} -m tests.fuzz.servers.misbehaving_backend --bind {{target_host}}:{{target_port}} "
             f"--mode flaky-crash --state {tmp_path / 'count'} --lifetime 120")
    # triage's share of 30 s (7.5 s) holds a baseline, the replay that shows it and 3 confirming
    # ones that wait 1 s each for a death
    run = _fuzz("--spawn", spawn, "--duration", "30", "--out", str(tmp_path / "out"))
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    print(run.stdout + run.stderr, summary["environment_dependent"])
    env = [e for e in summary["environment_dependent"] if e["rule"] == "NSQD-ROB-1"]
    assert len(env) == 1 and "crash" in env[0]["shape"] and env[0]["why"].startswith("reproduced 1 of 4"), env
    assert not any(f["oracle"] == "crash" for f in summary["findings"]), summary["findings"]
    assert "environment-dependent (not a finding): NSQD-ROB-1" in run.stdout, run.stdout


def test_a_death_on_a_command_read_late_is_a_crash_not_its_effect_missing():
    """A backend held off the CPU reads a judged command late and dies of it, after it served
    the new connection the fuzzer's FIN opened (an UPDATE, the state unchanged:
    misbehaving_backend --mode late-crash): the case's hit is the death (NSQD-ROB-1), as
    ``_effect``'s other ends and the stateful player judge one first, not NSQD-MSG-3 (the
    flaky-crash campaign above found an "effect" first at load ~11, its crash then unconfirmed)."""
    from mcp_conform.fuzz.nsqd_backend import Backend
    from mcp_conform.fuzz.nsqd_mutators import Case, Write
    from mcp_conform.spec import NSQD
    from mcp_conform.spec.nsqd_codec import encode

    b = Backend(None, _spawn("late-crash"))
    try:
        msg = NSQD.message("TAKEOFF")
        case = Case("valid", (Write(encode(NSQD, "TAKEOFF")),), True, "TAKEOFF", expect=msg.effect.to,
                    or_error=msg.effect.or_error, check=True, msg="TAKEOFF")
        hit = b.run(case)
        assert hit is not None and hit.signature.oracle == "crash" and hit.signature.rule == "NSQD-ROB-1", hit
    finally:
        b.close()
