"""Restarts timed on their own and made cheap (issue 36 item 5): against the C backend built
with ASan that over-reads on every frame (tests/nsqd_backends), nearly every case is a crash
whose signature is already confirmed; the backend is restarted for the next case, and that is
no triage. ``Backend.restart`` hands over a spare started in the background (alive when taken:
a spare started on a thread that then ended was killed by its parent-death signal), and the
campaign's summary and last line give fuzzing, triage and restarts apart."""

from __future__ import annotations

from pathlib import Path

import pytest

from mcp_conform.fuzz.nsqd_backend import Backend
from mcp_conform.fuzz.nsqd_campaign import StreamCampaign
from tests.forkserver import run_module
from tests.nsqd_backends.build import built_or_skip

pytestmark = [pytest.mark.nsqd]

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def spawn() -> str:
    exe = built_or_skip()
    return f"{exe} --host {{target_host}} --port {{target_port}} --fault overread-every-frame"


def test_a_restart_takes_the_spare_started_before_it(spawn):
    b = Backend(None, spawn)
    try:
        b = b.restart()
        assert len(b.pool.spares.queue) == 2  # a replay may take less than a real backend's start: two ahead
        spare = b.pool.spares.queue[0].future.result(timeout=30)
        b = b.restart()
        assert b is spare and b.process is not None and b.process.alive()
        assert b.session.live(2.0)  # it serves
    finally:
        b.close()


@pytest.mark.slow
def test_restarts_after_counted_crashes_are_not_triage(tmp_path, spawn):
    c = StreamCampaign(None, spawn, 20140307, 12.0, None, tmp_path)
    s = c.run()
    print({k: s[k] for k in ("cases", "elapsed_s", "fuzz_s", "triage_s", "restart_s", "restarts", "triage_share")})
    crashes = next(f["count"] for f in s["findings"] if f["oracle"] == "crash")
    assert crashes > 1 and s["restarts"] >= crashes - 1, s  # each counted crash restarted the backend
    assert s["fuzz_s"] + s["triage_s"] + s["restart_s"] <= s["elapsed_s"] + 0.5, s
    # the share is triage's own time over the elapsed time; the summary rounds all three, so
    # the share recomputed from the rounded seconds may differ in its last digit (0.639/0.64)
    assert abs(s["triage_share"] - s["triage_s"] / s["elapsed_s"]) <= 0.002, s


@pytest.mark.slow
def test_the_last_line_gives_fuzzing_triage_and_restarts(tmp_path, spawn):
    run = run_module("mcp_conform.fuzz", ["--protocol", "nsqd", "--spawn", spawn, "--duration", "5"], timeout=120,
                     cwd=ROOT)  # a child of tests/forkserver.py
    last = run.stdout.strip().splitlines()[-1]
    print(last)
    assert "fuzzing " in last and "triage " in last and "restarts " in last and "grace" in last, last
