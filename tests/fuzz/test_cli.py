"""mcp-fuzz's command line: help, one-line usage errors (exit 2), findings round trip."""

from __future__ import annotations

import json

import pytest

from mcp_conform.fuzz.cli import UsageError, main
from mcp_conform.fuzz.ddmin import ddmin
from mcp_conform.fuzz.findings import Finding, FindingStore, load_finding
from tests.capturing import free_port


def test_help_exits_0(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    assert "--engine" in capsys.readouterr().out


@pytest.mark.parametrize("argv, words", [
    (["--jobs", "x"], "--jobs"),
    (["--engine", "fast"], "--engine"),
    (["--duration", "-1"], "--duration"),
    (["--target", "nohost:port"], "--target"),
    (["--target", "127.0.0.1:9", "--jobs", "2"], "--jobs"),
    (["--db", "ftp://x"], "--db"),
    (["--target", "127.0.0.1:9", "--spawn", "x"], "not allowed"),
    (["--replay", "/nonexistent/finding-1"], "--replay"),
    (["--role", "pilot"], "--role"),
    (["--role", "manager", "--engine", "stateful"], "--engine"),
])
def test_bad_arguments_are_one_line_errors(argv: list[str], words: str,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err and "Traceback" not in err


def test_finding_written_and_loaded_with_repro_capture(tmp_path) -> None:  # noqa: ANN001
    from mcp_conform.traceio.reader import Datagram, Metadata, open_capture

    store = FindingStore(tmp_path, ["--mavlink"])
    f = Finding("MCP-ACK-4", "no ACK", "an ACK", ["4e4353552d434d0101ffff000000010005"], "replies: valid",
                "stateless", 5)
    d = store.add(f)
    assert d is not None and (d / "replay.txt").read_text().startswith("mcp-fuzz --replay ")
    assert load_finding(d).datagrams == f.datagrams
    assert load_finding(d / "repro.mcap").datagrams == f.datagrams  # read as every finding is
    body = json.loads((d / "finding.json").read_text())
    assert body["rule"] == "MCP-ACK-4" and body["level"] == "MUST" and body["seed"] == 5
    recs = [r for r in open_capture(d / "repro.mcap") if isinstance(r, Datagram)]
    assert [r.data.hex() for r in recs] == f.datagrams
    meta = [r for r in open_capture(d / "repro.mcap") if isinstance(r, Metadata)]
    assert len(meta) == 1 and meta[0].data["recorder"] == "mcp-fuzz", meta
    assert meta[0].data["rule"] == "MCP-ACK-4" and meta[0].data["seed"] == "5", meta
    from mcp_conform.fuzz.findings import finding_from_metadata

    back = finding_from_metadata(meta[0].data)  # what mcp-capture replay reproduces
    assert back is not None and (back.rule, back.datagrams, back.pace) == (f.rule, f.datagrams, f.pace)
    assert finding_from_metadata({**meta[0].data, "recorder": "mcp-conform"}) is None
    store.add(Finding("MCP-ACK-4", "no ACK", "an ACK", ["00"], "replies: valid", "stateless", 5))
    assert len(store) == 1 and store.by_rule() == {"MCP-ACK-4": 2}


def test_shrink_finds_the_minimal_pair() -> None:
    seq = [bytes([i]) for i in range(40)]
    calls = []

    def fails(s: list[bytes]) -> bool:
        calls.append(1)
        return b"\x07" in s and b"\x21" in s

    assert sorted(ddmin(seq, fails, 200, singles=8)) == [b"\x07", b"\x21"]


def test_seeds_are_the_sent_datagrams_of_mcap_captures(tmp_path) -> None:  # noqa: ANN001
    from mcp_conform.fuzz.campaign import load_seeds
    from mcp_conform.harness.errors import SetupError
    from mcp_conform.traceio.recorder import McapRecorder

    sent = [bytes.fromhex("4e4353552d434d010100010000000a0005"), b"\x01\x02"]
    with McapRecorder(tmp_path / "a.mcap") as rec:
        for d in sent:
            rec.datagram("tx", d, ("127.0.0.1", 7890))
        rec.datagram("rx", bytes.fromhex("4e4353552d434d010100000001000b0007000a"), ("127.0.0.1", 7890))
    assert load_seeds(str(tmp_path)) == sent
    with pytest.raises(SetupError, match="--seeds"):
        load_seeds(str(tmp_path / "none"))


def test_progress_off_a_terminal_is_a_plain_status_line_every_few_seconds(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 18 item 11: a CI log shows the campaign's progress while it runs (before: nothing
    until the end), a line per ``STATUS_S``, not one per update; then the summary."""
    import io

    import mcp_conform.fuzz.progress  # noqa: F401  (the attribute the next line's name reaches)
    from mcp_conform import fuzz
    from mcp_conform.fuzz.config import FuzzConfig
    from mcp_conform.fuzz.progress import LiveProgress, Progress

    clock = [100.0]
    monkeypatch.setattr(fuzz.progress.time, "monotonic", lambda: clock[0])
    out = io.StringIO()
    live = LiveProgress(FuzzConfig(engine="stateful"), out)
    with live:
        live.update(Progress(cases=10, fuzz_seconds=1.0))
        assert out.getvalue() == ""  # not yet STATUS_S
        clock[0] += fuzz.progress.STATUS_S
        live.update(Progress(cases=1234, fuzz_seconds=2.0, findings=1))
        live.update(Progress(cases=1300, fuzz_seconds=2.1, findings=1))  # within the next period
    lines = out.getvalue().splitlines()
    assert len(lines) == 1, lines
    assert "stateful" in lines[0] and "cases 1,234" in lines[0] and "findings 1" in lines[0], lines
    summary = {"cases": 10, "duration_s": 1.0, "judged_cases_per_s": 10.0, "findings": 0,
               "findings_by_rule": {}, "seed": 1, "restarts": 0}
    live.final(summary, FindingStore(None))
    assert out.getvalue().count("\n") == 3 and "10 judged cases/s" in out.getvalue()
    assert "triage 0 s of 1.0 s" in out.getvalue()  # where the time went (issue 36)


def test_status_every_sets_the_period_of_the_plain_status_line(monkeypatch: pytest.MonkeyPatch) -> None:
    """``--status-every S``: a CI log's status line every S seconds, not every STATUS_S; a
    period that is not a positive number is a one-line usage error."""
    import io

    import mcp_conform.fuzz.progress  # noqa: F401  (the attribute the next line's name reaches)
    from mcp_conform import fuzz
    from mcp_conform.fuzz.cli import build_parser, make_config
    from mcp_conform.fuzz.progress import LiveProgress, Progress

    clock = [100.0]
    monkeypatch.setattr(fuzz.progress.time, "monotonic", lambda: clock[0])
    cfg = make_config(build_parser().parse_args(["--status-every", "0.5"]))
    nsqd = make_config(build_parser().parse_args(["--protocol", "nsqd", "--status-every", "0.5"]))
    assert cfg.extra["status_every"] == 0.5 and LiveProgress(nsqd, every=nsqd.extra["status_every"]).every == 0.5
    out = io.StringIO()
    with LiveProgress(cfg, out, every=cfg.extra["status_every"]) as live:
        for _ in range(4):
            clock[0] += 0.5
            live.update(Progress(cases=10, fuzz_seconds=1.0))
    assert len(out.getvalue().splitlines()) == 4
    for bad in ("0", "-1", "soon"):
        with pytest.raises(UsageError, match="--status-every"):
            make_config(build_parser().parse_args(["--status-every", bad]))


@pytest.mark.parametrize("levels, strict, code", [
    ((), False, 0),
    (("SHOULD",), False, 0),   # reported, not counted (as mcp-conform and mcp-capture check)
    (("SHOULD",), True, 1),
    (("MUST",), False, 1),
    (("SHOULD", "MUST"), False, 1),
])
def test_one_convention_for_should_findings(monkeypatch: pytest.MonkeyPatch, tmp_path,
                                            levels: tuple[str, ...], strict: bool, code: int) -> None:
    """Issue 18 item 12: mcp-fuzz exits 1 on a SHOULD finding only under --strict."""
    import mcp_conform.fuzz.campaign  # noqa: F401  (the attribute the next line's name reaches)
    from mcp_conform import fuzz
    rules = {"SHOULD": "MCP-ROB-4", "MUST": "MCP-ROB-1"}

    def campaign(cfg, store, progress=None):  # a campaign that confirmed these findings
        for level in levels:
            store.add(Finding(rules[level], "x", "y", ["00"], "replies: valid", "stateless", 1))
        return {"cases": 1, "findings": len(store)}

    monkeypatch.setattr(fuzz.campaign, "run_campaign", campaign)
    monkeypatch.setattr("mcp_conform.fuzz.progress.LiveProgress.final", lambda self, summary, store: None)
    argv = ["--max-cases", "1", "--out", str(tmp_path)] + (["--strict"] if strict else [])
    assert main(argv) == code


@pytest.mark.parametrize("engine", ["stateless", "stateful"])
def test_outputs_and_services_are_checked_before_the_campaign(tmp_path, engine: str,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 19 item 5: a read-only --out and an unreachable --db redis://... are one-line
    errors (exit 2) before any case runs, for both engines, never a traceback at the end."""
    import os
    import socket

    ro = tmp_path / "ro"
    ro.mkdir()
    os.chmod(ro, 0o500)
    if os.access(ro, os.W_OK):  # root writes anywhere: a file where the directory should be
        os.chmod(ro, 0o700)
        ro = tmp_path / "file" / "out"
        (tmp_path / "file").write_text("x")
    dead = free_port(socket.SOCK_STREAM)  # a port nothing listens on
    for argv, words in ((["--out", str(ro)], "--out"),
                        (["--db", f"redis://127.0.0.1:{dead}/0"], "cannot reach")):
        assert main(["--engine", engine, "--max-cases", "1", *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and words in err and "Traceback" not in err, err


def test_repro_capture_holds_the_whole_finding_and_its_marks_in_order(tmp_path) -> None:
    """One way back from a recorded finding (finding.json or repro.mcap's metadata record),
    program, evidence and source included; the case marks enclose the traffic (issue 18
    item 13: the start mark came after the end mark)."""
    import time as _time

    from mcp_conform.fuzz.findings import finding_from_metadata, write_repro
    from mcp_conform.traceio.reader import CaseMark, Datagram, Metadata, open_capture

    f = Finding("MCP-DUP-1", "once", "twice", ["00ff"], "passthrough", "stateful", 3,
                program="state.command(...)", evidence=["vehicle: token x delivered 2 times"],
                source="vehicle", scenario="withhold:2", target={"spawn": "node --id {id}"})
    t = _time.time_ns() - 5_000_000_000  # traffic recorded seconds before the file is written
    traffic = [("tx", t, b"\x00\xff", ("127.0.0.1", 7890)), ("rx", t + 1000, b"\x01", ("127.0.0.1", 7890))]
    path = tmp_path / "repro.mcap"
    write_repro(path, f, traffic)
    recs = list(open_capture(path))
    meta = next(r for r in recs if isinstance(r, Metadata))
    back = finding_from_metadata(meta.data)
    assert back == f
    marks = [r for r in recs if isinstance(r, CaseMark)]
    data = [r for r in recs if isinstance(r, Datagram)]
    assert [m.event for m in marks] == ["start", "end"]
    assert marks[0].t_ns <= data[0].t_ns <= data[-1].t_ns <= marks[1].t_ns


def test_ddmin_tries_the_last_items_alone_first_then_complements() -> None:
    """One ddmin for both protocols: MCP's triage asks for singles first (a lone datagram is
    the usual reproducer), Nsqd's campaign does not; both end at the same minimal pair."""
    tried: list[list[int]] = []

    def fails(xs: list[int]) -> bool:
        tried.append(xs)
        return 1 in xs and 8 in xs

    assert ddmin(list(range(10)), fails, 40, singles=8) == [1, 8]
    assert tried[:8] == [[9], [8], [7], [6], [5], [4], [3], [2]]
    tried.clear()
    assert ddmin(list(range(10)), fails, 40) == [1, 8] and len(tried[0]) == 5  # a half first
    assert ddmin(list(range(10)), lambda xs: 7 in xs, 40, singles=8) == [7]


def test_a_role_no_fuzzer_drives_is_refused_in_one_line() -> None:
    """``--role gcs`` of MAVLink: the profile says no campaign fuzzes a ground station
    (``RoleProfile.fuzzed``), so ``mcp-fuzz`` refuses it in one line naming the roles it does
    fuzz, rather than fuzz the command given as a vehicle; the roles it fuzzes still pass."""
    from mcp_conform.fuzz.cli import build_parser, make_config

    with pytest.raises(UsageError, match=r"--role: a gcs \(mavlink\) is not fuzzed yet \(roles fuzzed: vehicle\)"):
        make_config(build_parser().parse_args(["--protocol", "mavlink", "--role", "gcs"]))
    assert make_config(build_parser().parse_args(["--protocol", "mavlink", "--role", "vehicle"])).role == "vehicle"
    assert make_config(build_parser().parse_args(["--role", "manager"])).role == "manager"
