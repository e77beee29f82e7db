"""mcp-capture's command line: subcommands registered by their modules, one-line errors."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from mcp_conform.captures.cli import SUBCOMMANDS, build_parser, main


def test_help_exits_zero_and_lists_every_subcommand():
    proc = subprocess.run([sys.executable, "-m", "mcp_conform.captures.cli", "--help"], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0, proc.stderr
    for module in SUBCOMMANDS:
        assert module.rsplit(".", 1)[1] in proc.stdout


@pytest.mark.parametrize("command", [m.rsplit(".", 1)[1] for m in SUBCOMMANDS])
def test_subcommand_help(command, capsys):
    with pytest.raises(SystemExit) as exc:
        build_parser().parse_args([command, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert f"usage: mcp-capture {command}" in out and "--help" in out


@pytest.mark.parametrize("argv,words", [
    ([], "a COMMAND is required"),
    (["frobnicate"], "invalid choice"),
    (["check"], "required: FILE"),
    (["check", "x.pcap", "--bogus"], "unrecognized arguments"),
])
def test_usage_errors_exit_2(argv, words, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert words in err and err.startswith("mcp-capture: error: ") and err.count("\n") == 1, err


@pytest.mark.parametrize("content,words", [
    (b"", "empty file"),
    (b"not a capture at all", "not a capture"),
])
def test_unreadable_input_exit_2_one_line(tmp_path, capsys, content, words):
    path = tmp_path / "bad.pcap"
    path.write_bytes(content)
    for command in ("check", "show"):
        assert main([command, str(path)]) == 2
        err = capsys.readouterr().err
        assert err.startswith("mcp-capture: error: ") and words in err and err.count("\n") == 1


@pytest.mark.parametrize("option,value,words", [
    ("--rto", "0", "--rto: must be a positive"),
    ("--ack-window", "abc", "--ack-window: not a number"),
    ("--challenge", "4", "--challenge: 4 is outside 1-3"),
    ("--drones", "1,0", "--drones"),
    ("--drones", "1,1", "--drones"),
    ("--waypoints", "/nonexistent.waypoints", "--waypoints"),
    ("--json", "/nonexistent/dir/out.json", "--json: directory"),
])
def test_bad_option_values_exit_2(tmp_path, capsys, option, value, words):
    from scapy.utils import wrpcap

    path = tmp_path / "empty.pcap"
    # the link type named: scapy logs no "unknown LL type" warning, which went to a logging
    # handler an earlier test left on its closed capsys stream ("--- Logging error ---")
    wrpcap(str(path), [], linktype=1)
    assert main(["check", str(path), option, value]) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1


GOLDEN = Path(__file__).resolve().parents[2] / "captures" / "golden"


@pytest.mark.parametrize(("argv", "code"), [
    (["diff", str(GOLDEN / "challenge1.mcap"), str(GOLDEN / "challenge2.mcap")], 1),
    (["diff", str(GOLDEN / "challenge1.mcap"), str(GOLDEN / "challenge1.mcap")], 0),
    (["check", str(GOLDEN / "drone-suite.mcap")], 0),
], ids=["diff-different", "diff-same", "check"])
def test_a_reader_that_goes_away_loses_neither_the_files_nor_the_verdict(tmp_path, argv, code):
    """`mcp-capture diff a b | head -1` (issue 18 item 14): the --json and --html files are
    written and the exit code is the verdict's, whatever happens to the terminal report."""
    js, html = tmp_path / "out.json", tmp_path / "out.html"
    cmd = [sys.executable, "-m", "mcp_conform.captures", *argv, "--json", str(js), "--html", str(html)]
    script = " ".join(f"'{w}'" for w in cmd) + " | head -c 1 >/dev/null; exit ${PIPESTATUS[0]}"
    proc = subprocess.run(["bash", "-c", script], capture_output=True, text=True, timeout=120)
    assert proc.returncode == code, proc.stderr
    assert js.stat().st_size > 0 and html.stat().st_size > 0
    assert "Traceback" not in proc.stderr and "Broken pipe" not in proc.stderr, proc.stderr
