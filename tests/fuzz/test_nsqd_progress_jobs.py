"""``mcp-fuzz --protocol nsqd`` progress, summary.json and --jobs (issue 21 item 5): the live
figures (cases, judged cases/s, findings by class, the kinds x message ids table) on a
terminal and as plain lines off one; summary.json holding them; workers with their own
backends sharing the example database (a program one campaign saved is replayed first)."""

from __future__ import annotations

import io
import json
import time
from pathlib import Path

import pytest

import mcp_conform.fuzz.progress  # noqa: F401  (the attribute the next line's name reaches)
from mcp_conform import fuzz
from mcp_conform.fuzz.config import FuzzConfig
from mcp_conform.fuzz.nsqd_campaign import StreamCampaign
from mcp_conform.fuzz.progress import LiveProgress, Progress, tried_table
from mcp_conform.spec import NSQD
from tests.forkserver import run_module
from tests.nsqd_backends.build import built_or_skip

NSQD_CFG = FuzzConfig(protocol="nsqd", role="backend", engine="both")


def _view(**kw: object) -> Progress:
    base = dict(cases=1200, fuzz_seconds=10.0, restarts=2, started=time.monotonic() - 12, findings=3,
                tried={"length-lie": {"TAKEOFF": 7, "unknown": 1}, "valid": {"SET_PID": 1500}},
                classes={"close": 1, "crash": 2})
    base.update(kw)
    return Progress(**base)  # type: ignore[arg-type]


def test_off_a_terminal_a_plain_status_line(monkeypatch):
    monkeypatch.setattr(fuzz.progress, "STATUS_S", 0.0)  # the display every campaign shares
    out = io.StringIO()
    with LiveProgress(NSQD_CFG, out) as live:
        live._next_status = 0.0
        live.update(_view())
    line = out.getvalue()
    assert line.count("\n") == 1 and "\x1b" not in line
    assert "nsqd both" in line and "cases 1,200" in line and "120 judged cases/s" in line
    assert "findings 3 (close 1, crash 2)" in line


def test_both_campaigns_share_one_display(monkeypatch):
    """MCP's and Nsqd's progress are one display (fuzz.progress.LiveProgress): the status line's
    period is the one STATUS_S, a line per due update, and on a terminal one rich Live."""
    clock = [1000.0]
    monkeypatch.setattr(fuzz.progress.time, "monotonic", lambda: clock[0])
    for cfg, view in ((NSQD_CFG, _view()), (FuzzConfig(engine="stateful"), Progress())):
        out = io.StringIO()
        with LiveProgress(cfg, out) as live:
            live.update(view)
            assert out.getvalue() == ""  # not yet STATUS_S
            clock[0] += fuzz.progress.STATUS_S
            live.update(view)
            live.update(view)
        assert out.getvalue().count("\n") == 1 and out.getvalue().startswith("mcp-fuzz: ")
        assert f"{cfg.protocol} {cfg.engine}" in out.getvalue()


def test_on_a_terminal_the_table_of_kinds_by_message_ids():
    from rich.console import Console

    cols, rows = tried_table(_view().tried, NSQD.messages)
    assert cols[:2] == ["0", "1"] and cols[-2:] == ["?", "-"]
    assert dict(rows)["length-lie"][4] == 7 and dict(rows)["length-lie"][-2] == 1  # TAKEOFF is id 4
    console = Console(record=True, width=120, file=io.StringIO())
    console.print(LiveProgress(NSQD_CFG, io.StringIO()).render(_view()))
    text = console.export_text()
    assert "findings 3 (close 1, crash 2)" in text and "120 judged cases/s" in text
    row = next(line for line in text.splitlines() if line.strip().startswith("valid"))
    assert "1k" in row and row.count("·") == len(cols) - 1
    console = Console(record=True, width=120, file=io.StringIO())  # no table when none is counted
    console.print(LiveProgress(FuzzConfig(), io.StringIO()).render(Progress(cases=3)))
    assert f"mcp {FuzzConfig().engine}" in console.export_text() and "mutation kind" not in console.export_text()


def _spawn(exe: Path, fault: str | None = None) -> str:
    return f"{exe} --host {{target_host}} --port {{target_port}} --update-period 0.1" + (f" --fault {fault}" if fault else "")


@pytest.mark.slow
@pytest.mark.nsqd
def test_summary_json_and_plain_progress_from_the_command_line(tmp_path):
    """A plain status line each ``--status-every`` s off a terminal (default 10 s: a 12 s
    campaign was run for it), summary.json."""
    run = run_module("mcp_conform.fuzz", ["--protocol", "nsqd", "--duration", "4", "--status-every", "1", "--out",
                                          str(tmp_path), "--engine", "both"], timeout=120)  # tests/forkserver.py
    assert run.returncode == 0, run.stdout + run.stderr
    status = [line for line in run.stdout.splitlines() if "judged cases/s  findings" in line]
    assert status and "nsqd both" in status[0], run.stdout
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["engine"] == "both" and s["cases"] > 0 and s["findings"] == [] and s["findings_by_class"] == {}
    assert 0 < s["fuzz_s"] <= s["elapsed_s"] and s["judged_cases_per_s"] >= s["cases_per_s"]
    # every case is in the table, under its kind, once per message id it sent ("-": none), so the
    # table's sum is at least the cases, whichever engine ran them (a campaign starved of CPU
    # may spend the stateless turn starting its backend: the cases by engine say so)
    assert sum(n for row in s["tried"].values() for n in row.values()) >= s["cases"]
    assert sum(s["cases_by_engine"].values()) == s["cases"] and set(s["cases_by_engine"]) == {"stateless", "stateful"}
    assert "valid" in s["tried"] and set(s["by_kind"]) <= set(s["tried"])  # the stateless turn's kinds in it


@pytest.mark.nsqd
def test_every_case_of_a_program_is_in_the_tried_table(tmp_path):
    """The stateful engine's ops that send no bytes (a connect, a close) are cases too: each is
    in ``tried`` under ``connect`` or ``close``, its one count under ``-`` (no message id).
    (They were counted in ``cases`` and nowhere in the table: a starved ``--engine both``
    campaign, all its cases the stateful turn's, had 198 of 256 in it.)"""
    s = StreamCampaign(None, None, 20140307, 60.0, 256, tmp_path, engine="stateful").run()
    assert s["cases"] == 256 and s["cases_by_engine"] == {"stateful": 256}, s
    assert sum(n for row in s["tried"].values() for n in row.values()) >= s["cases"], s["tried"]
    assert s["tried"]["connect"] == {"-": s["tried"]["connect"]["-"]} and s["tried"]["connect"]["-"] > 0, s["tried"]
    assert set(s["tried"].get("close", {})) <= {"-"}, s["tried"]


@pytest.mark.slow
@pytest.mark.nsqd
def test_jobs_share_the_example_database(tmp_path):
    """A program saved by one campaign is the first the workers of the next replay: with two
    cases each they find the second-client fault; with an empty database they do not."""
    exe = built_or_skip()
    spawn, db = _spawn(exe, "second-client-kicks-first"), str(tmp_path / "db")
    first = StreamCampaign(None, spawn, 3, 60.0, None, None, engine="stateful", db=db, stop_after=1)
    first.run()
    assert [f.signature.rule for f in first.findings] == ["NSQD-CON-2"]
    assert any((tmp_path / "db").iterdir())

    def jobs(database: str, out: Path) -> dict:
        c = StreamCampaign(None, spawn, 11, 60.0, 4, out, engine="stateful", db=database)
        out.mkdir()
        return c.run_jobs(2)

    control = jobs(str(tmp_path / "empty-db"), tmp_path / "control")
    assert control["findings"] == [] and len(control["workers"]) == 2, control
    shared = jobs(db, tmp_path / "shared")
    assert [f["rule"] for f in shared["findings"]] == ["NSQD-CON-2"], shared
    assert [w["findings"] for w in shared["workers"]] == [1, 1] and shared["findings"][0]["count"] == 2
    assert (tmp_path / "shared" / "finding-1" / "finding.json").is_file()
    assert not (tmp_path / "shared" / "finding-2").exists()
