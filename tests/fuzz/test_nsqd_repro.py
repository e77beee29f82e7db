"""An Nsqd finding's repro.mcap and repro.pcap (issue 21 item 3), from a short seeded campaign
against the C backend of tests/nsqd_backends (a negative string length it trusts, read past
its heap buffer under AddressSanitizer): repro.mcap holds the whole finding (read back as
finding.json is) and the confirming replay's traffic; repro.pcap is that traffic as a TCP
conversation — handshake, the input, the dead backend's FIN — that tshark's "Follow TCP
stream" turns back into the finding's input; ``mcp-capture replay`` of the directory, the
MCAP or the pcap reproduces it against the faulty backend (exit 1) and not against the
correct one (exit 0), as ``mcp-fuzz --protocol nsqd --replay`` does."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

from mcp_conform.fuzz.finding_files import read_finding_doc
from mcp_conform.fuzz.findings import read_finding
from mcp_conform.spec import NSQD
from mcp_conform.spec.nsqd_codec import Deframer, Frame
from mcp_conform.traceio.nsqd import stream_records
from mcp_conform.traceio.reader import Metadata, StreamEvent, StreamFrame, open_capture
from tests.forkserver import run_module
from tests.nsqd_backends.build import built_or_skip
from tests.nsqd_backends.findings import class_finding
from tests.nsqd_backends.findings import spawn as _spawn

pytestmark = [pytest.mark.slow, pytest.mark.nsqd]

ROOT = Path(__file__).resolve().parents[2]
ENV = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
FAULT = "crash-on-negative-string"


@pytest.fixture(scope="module")
def finding(tmp_path_factory) -> tuple[Path, Path]:
    """The backend and the campaign's finding directory, found once per test session
    (tests/nsqd_backends/findings.py: tests/fuzz/test_nsqd_fuzz.py's campaign against this
    fault; CI's slow run ran it on three workers, and once more there): read-only."""
    exe = built_or_skip()
    made = class_finding(tmp_path_factory, exe, FAULT)
    assert made["oracles"] == ["crash"], made["summary"]
    return exe, made["dir"] / "finding-1"


def assert_input_then_commands(sent: bytes, data: bytes) -> None:
    """What the client sent on the finding's connection: the finding's input, then nothing but
    whole client commands, the campaign's probes of a backend it had not yet seen die (a loaded
    CI run's ASan backend closed its socket 2 s after the input, and got a STOP_TEST first)."""
    assert sent[:len(data)] == data
    deframer = Deframer(NSQD)
    after = deframer.feed(sent[len(data):])
    assert deframer.pending == 0 and all(type(f) is Frame and NSQD.message(f.msg_id).sent_by == "client"
                                         for f in after), after


def test_repro_mcap_holds_the_finding_and_its_traffic(finding):
    _, d = finding
    doc = json.loads((d / "finding.json").read_text())
    assert read_finding_doc(d / "repro.mcap") == doc == read_finding(d, "nsqd").to_json()
    meta = [r for r in open_capture(d / "repro.mcap") if type(r) is Metadata]
    assert meta[0].data["recorder"] == "mcp-fuzz" and meta[0].data["protocol"] == "nsqd"
    recs = [r for r in stream_records(d / "repro.mcap") if type(r) in (StreamFrame, StreamEvent)]
    sent = b"".join(r.raw for r in recs if type(r) is StreamFrame and r.direction == "tx" and r.conn == 1)
    assert_input_then_commands(sent, bytes.fromhex((d / "input.hex").read_text()))
    events = [(r.event, r.by) for r in recs if type(r) is StreamEvent]
    assert events[0] == ("open", None) and ("close", "backend") in events  # the backend died: its socket closed


def test_repro_pcap_is_a_tcp_conversation_tshark_follows_to_the_input(finding):
    if shutil.which("tshark") is None:
        pytest.skip("tshark is not installed (bash .ci/apt-tools)")
    from tests.captures.tshark_follow import follow

    _, d = finding
    data = bytes.fromhex((d / "input.hex").read_text())
    client, _server = follow(d / "repro.pcap", 0)
    assert_input_then_commands(client, data)
    flags = subprocess.run(["tshark", "-r", str(d / "repro.pcap"), "-T", "fields", "-e", "tcp.flags.str"],
                           capture_output=True, text=True, timeout=60).stdout.split("\n")
    assert "S" in flags[0] and "S" in flags[1] and "A" in flags[1]  # SYN, SYN-ACK
    assert any("F" in f for f in flags)  # the backend's FIN as its process exited
    # our own reader agrees with tshark
    recs = list(stream_records(d / "repro.pcap"))
    assert b"".join(r.raw for r in recs if type(r) is StreamFrame and r.direction == "tx" and r.conn == 1) == client


@pytest.mark.parametrize("what", [".", "repro.mcap", "repro.pcap"])
def test_mcp_capture_replay_reproduces_it_or_not(finding, what):
    exe, d = finding
    for spawn, want in ((_spawn(exe, FAULT), 1), (_spawn(exe), 0)):
        run = run_module("mcp_conform.captures", ["replay", str(d / what), "--spawn", spawn], env=ENV, cwd=ROOT,
                         timeout=120)  # a child of tests/forkserver.py
        assert run.returncode == want, (spawn, run.stdout, run.stderr)
        assert ("reproduced NSQD-ROB-1" if want else "did not reproduce") in run.stdout


def test_replay_of_a_file_that_is_no_finding_is_one_line_exit_2(tmp_path):
    bad = tmp_path / "finding-9"
    bad.mkdir()
    (bad / "finding.json").write_text('{"protocol": "nsqd"}')
    run = run_module("mcp_conform.fuzz", ["--protocol", "nsqd", "--replay", str(bad)], env=ENV, cwd=ROOT, timeout=120)
    # one line on stderr, as every protocol's replay says an unreadable finding (fuzz.replay_core)
    assert run.returncode == 2 and run.stderr.count("\n") == 1 and "is not a finding" in run.stderr, run
    assert "Traceback" not in run.stderr and not run.stdout, run
