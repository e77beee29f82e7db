"""``mcp-fuzz --protocol nsqd`` (issue 21) against the C backend of tests/nsqd_backends, built
with AddressSanitizer: one fault of each class the issue names is found in a short seeded
campaign as one confirmed, minimised finding whose replay reproduces it (exit 1) against the
faulty backend and not (exit 0) against the correct one; the reference backend gives none."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from mcp_conform.fuzz.nsqd_campaign import StreamCampaign
from tests.forkserver import run_module
from tests.nsqd_backends.build import built_or_skip
from tests.nsqd_backends.findings import class_finding
from tests.nsqd_backends.findings import spawn as _spawn

pytestmark = [pytest.mark.slow, pytest.mark.nsqd]

#: fault -> (oracle, rule) of the finding: the eight classes of C network code of issue 21
CLASSES = {
    "overread-every-frame": ("crash", "NSQD-ROB-1"),      # a heap over-read on every frame
    "unknown-id-no-skip": ("desync", "NSQD-MSG-4"),       # a trusted length that desynchronises
    "crash-on-negative-string": ("crash", "NSQD-ROB-1"),  # a negative or overlong string length
    "crash-on-bad-number": ("crash", "NSQD-ROB-1"),       # a numeric parse that aborts
    "early-return-keeps-size": ("desync", "NSQD-MSG-7"),  # an early return keeps the frame state
    "switch-fallthrough": ("effect", "NSQD-MSG-3"),       # a switch that falls through
    "fd-leak": ("leak", "NSQD-CON-3"),                    # a close never detected
    "unbounded-gpx-alloc": ("hang", "NSQD-MSG-1"),        # a parser that spins and allocates
}


@pytest.fixture(scope="module")
def backend() -> Path:
    return built_or_skip()


@pytest.mark.parametrize("fault", sorted(CLASSES))
def test_each_class_is_found_confirmed_and_replays(tmp_path_factory, backend, fault):
    """The campaign (seed 20140307, stopped at its first confirmed finding) is made once per
    session: tests/fuzz/test_nsqd_repro.py reads crash-on-negative-string's too
    (tests/nsqd_backends/findings.py); its files are read only."""
    oracle, rule = CLASSES[fault]
    made = class_finding(tmp_path_factory, backend, fault)
    summary, out = made["summary"], made["dir"]
    assert made["oracles"] == [oracle], summary
    assert made["rules"][0] == rule
    doc = json.loads((out / "finding-1" / "finding.json").read_text())
    assert doc["rule"] == rule and doc["replays"] == "3 of 3"  # a leak: its cycles on 3 fresh processes
    assert {"finding.json", "input.hex", "input.py", "stderr.txt", "replay.txt"} <= {p.name for p in (out / "finding-1").iterdir()}
    if oracle == "leak":
        return  # observed over the campaign's connections: NSQD-CON-3's conformance case replays it
    for spawn, want in ((_spawn(backend, fault), 1), (_spawn(backend), 0)):
        run = run_module("mcp_conform.fuzz", ["--protocol", "nsqd", "--replay", str(out / "finding-1"),
                                              "--spawn", spawn], timeout=120)  # a child of tests/forkserver.py
        assert run.returncode == want, (spawn, run.stdout, run.stderr)
    if oracle == "crash":
        # a sanitizer report names its kind and frames; a death without one its signal, or the
        # uncaught C++ exception that aborted it (crash-on-bad-number: std::stof's throw)
        assert doc["frames"] and doc["kind"] in ("heap-buffer-overflow", "stack-buffer-overflow") \
            or doc["kind"].startswith(("SIG", "abort: uncaught std::"))


def test_reference_backend_gives_no_finding(tmp_path):
    c = StreamCampaign(None, None, 7, 60.0, 1500, tmp_path)
    summary = c.run()
    assert summary["findings"] == [] and summary["cases"] == 1500, summary


@pytest.mark.parametrize("close_seen", [True, False])
def test_a_bad_id_desync_replays_however_soon_the_close_is_seen(tmp_path, backend, monkeypatch, close_seen):
    """unknown-id-no-skip reads a bad id's body as the next length and closes the connection;
    NSQD-MSG-4 says it must keep it. The replay's probe went to a new connection when the close
    had been seen by then (1 replay in 6: "did not reproduce", a CI failure) and on the old one
    when not: now it goes on the old one either way, as a connection that had to be kept."""
    import time

    import mcp_conform.fuzz.nsqd_campaign as sc

    writes = [{"hex": "0000000991834b4746", "end": ""}]  # id 145, 4 bytes of body
    (tmp_path / "finding.json").write_text(json.dumps({
        "protocol": "nsqd", "oracle": "desync", "kind": "stream lost after bad-id", "frames": [],
        "rule": "NSQD-MSG-4", "writes": writes, "expect": [], "probe": True}))
    run = sc.Backend.run

    def settled(self, case):  # the timing that lost the replay, or the other one, made certain
        hit = run(self, case)
        if close_seen and self.conn is not None:
            end = time.monotonic() + 2.0
            while self.conn.closed_at is None and time.monotonic() < end:
                self.conn.pump(0.05)
            assert self.conn.closed_at is not None
        return hit

    monkeypatch.setattr(sc.Backend, "run", settled)
    for fault, want in (("unknown-id-no-skip", 1), (None, 0)):
        if fault is None and close_seen:
            continue  # the correct backend keeps the connection: nothing to wait for
        assert sc.replay_stream_finding(str(tmp_path), None, _spawn(backend, fault)) == want, fault
