"""The tools' one grammar (issue 40): every tool's argparse parser checked against the tables of
docs/grammar.md, both ways (a tool the table says takes an option has it; one it says does not,
has not), with the old names as hidden aliases that warn once, the exit-code epilog in every
``--help``, ``--version``, and ``-`` for stdin and stdout run for real where it is cheap."""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.forkserver import run_module

ROOT = Path(__file__).resolve().parents[2]
TABLE = ROOT / "docs" / "grammar.md"
GOLDEN = ROOT / "captures" / "golden"
ENV = dict(os.environ, PYTHONPATH=str(ROOT), NO_COLOR="1")


def _builders() -> dict[str, object]:
    from mcp_conform.captures.cli import build_parser as capture
    from mcp_conform.conformance.cli import build_parser as conform
    from mcp_conform.fuzz.cli import build_parser as fuzz
    from mcp_conform.harness.impair_proxy import build_parser as impair
    from mcp_conform.reference_impl.cli import build_parser as node
    from mcp_conform.soak.cli import build_parser as soak
    from mcp_conform.vehicle.cli import build_parser as vehicle

    return {"conform": conform, "fuzz": fuzz, "capture": capture, "node": node, "impair": impair,
            "soak": soak, "vehicle": vehicle}


TOOLS = list(_builders())
COMMANDS = {"conform": ["mcp-conform"], "fuzz": ["mcp-fuzz"], "capture": ["mcp-capture"], "node": ["mcp-node"],
            "impair": ["mcp-impair"], "soak": ["mcp-soak"], "vehicle": [sys.executable, "-m", "mcp_conform.vehicle"]}


def _subparsers(p: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for a in p._actions:
        if isinstance(a, argparse._SubParsersAction):
            return dict(a.choices)
    return {}


def _options(p: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    return {s: a for a in p._actions for s in a.option_strings}


def _rows(heading: str) -> list[list[str]]:
    """The rows of the first table under ``## heading`` in docs/grammar.md, cells stripped."""
    text = TABLE.read_text(encoding="utf-8").split(f"## {heading}\n", 1)[1].split("\n## ", 1)[0]
    lines = [ln for ln in text.splitlines() if ln.startswith("|")]
    return [[c.strip() for c in re.split(r"(?<!\\)\|", ln)[1:-1]] for ln in lines[2:]]


def _option_rows() -> list[tuple[str, list[str], dict[str, str], str]]:
    out = []
    for cells in _rows("Options"):
        idea, option, *per_tool, old = cells
        names = re.findall(r"`(-{1,2}[\w-]+)", option)
        out.append((idea, names, dict(zip(TOOLS, per_tool, strict=True)), old))
    return out


OPTION_ROWS = _option_rows()


def test_the_table_names_every_tool_and_the_ideas_the_issue_lists() -> None:
    header = TABLE.read_text(encoding="utf-8")
    assert "| idea | option | conform | fuzz | capture | node | impair | soak | vehicle | old names |" in header
    firsts = {names[0] for _, names, _, _ in OPTION_ROWS}
    for opt in ("--target", "--listen", "--protocol", "--role", "--rto", "--json", "--junit", "--capture", "--out",
                "--select", "--exclude", "--strict", "--timeout", "--duration", "--live", "--impair", "--seed",
                "-v", "-q", "--version"):
        assert opt in firsts, opt


@pytest.mark.parametrize("idea,names,cells,old", OPTION_ROWS, ids=[r[1][0] for r in OPTION_ROWS])
def test_each_tool_spells_each_idea_as_the_table_says(idea, names, cells, old) -> None:
    builders = _builders()
    for tool, cell in cells.items():
        parser = builders[tool]()
        subs = _subparsers(parser)
        top = _options(parser)
        if cell == "(subcommand)":  # mcp-node: the role is the subcommand
            assert {"drone", "manager"} <= set(subs), (tool, idea)
            continue
        if cell == "—":
            where = {"": parser, **subs}
        elif cell == "✓":
            where = {}
            has = all(n in top for n in names) or (subs and all(all(n in _options(s) for n in names)
                                                                for s in subs.values()))
            assert has, f"{tool}: {names} ({idea}) missing"
        else:
            listed = [c.strip() for c in cell.split(",")]
            for name in listed:
                assert all(n in _options(subs[name]) for n in names), f"{tool} {name}: {names} missing"
            where = {k: v for k, v in subs.items() if k not in listed}
        for name, p in where.items():  # the table says not: then not, under any spelling
            present = [n for n in names if n in _options(p) and _options(p)[n].help != argparse.SUPPRESS]
            assert not present, f"{tool} {name}: {present} is there though the table says not ({idea})"


ALIASES = [(old_name, tool, names[0])
           for _, names, _, old in OPTION_ROWS for old_name, tool in re.findall(r"`(--[\w-]+)` \((\w+)\)", old)]


@pytest.mark.parametrize("old,tool,new", ALIASES, ids=[f"{t}:{o}" for o, t, _ in ALIASES])
def test_old_names_are_hidden_aliases_that_warn_once(old, tool, new, capsys) -> None:
    parser = _builders()[tool]()
    found = [(name, p) for name, p in {"": parser, **_subparsers(parser)}.items() if old in _options(p)]
    assert found, f"{tool}: {old} no longer accepted"
    for name, p in found:
        alias = _options(p)[old]
        assert alias.help == argparse.SUPPRESS, f"{tool} {name}: {old} shown in --help"
        value = None if alias.nargs == 0 else ("7" if alias.type is int else "127.0.0.1:7")
        args = ([name] if name else []) + [old] + ([value] if value is not None else [])
        required = {"drone": ["--id", "1"], "manager": ["--challenge", "1", "--drones", "1", "--waypoints", "x"],
                    "replay": ["x.mcap"]}.get(name, [])
        if tool == "impair":
            required = ["--listen", "127.0.0.1:0"]
        ns = parser.parse_args(args + required)
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "warning:" in err and old in err, err
        if new.startswith("--") and old not in ("--host", "--port", "--lenient"):
            dest = _options(p)[new].dest
            assert alias.dest == dest and getattr(ns, dest) is not None, (old, new)


def _all_parsers() -> list[tuple[str, argparse.ArgumentParser]]:
    out = []
    for tool, build in _builders().items():
        p = build()
        out.append((tool, p))
        out += [(f"{tool} {n}", s) for n, s in _subparsers(p).items()]
    return out


def test_every_help_ends_with_the_exit_codes() -> None:
    from mcp_conform.traceio.grammar import EXIT_CODES
    from mcp_conform.vehicle.cli import EXIT_CODES as VEHICLE_CODES

    assert VEHICLE_CODES == EXIT_CODES  # the vehicle's copy (it imports nothing of ours)
    for name, p in _all_parsers():
        assert p.format_help().rstrip().endswith(EXIT_CODES), name


def test_every_usage_error_is_one_line_with_one_prefix() -> None:
    """A bad option: one line, ``PROG: error: ...``, exit 2 (mcp-impair printed its whole usage,
    mcp-capture doubled its prefix)."""
    for tool, cmd in COMMANDS.items():
        run = subprocess.run([*cmd, "--no-such-option"], capture_output=True, text=True, env=ENV, timeout=120)
        prog = "mcp-vehicle" if tool == "vehicle" else cmd[0]
        assert run.returncode == 2, (tool, run.stderr)
        assert run.stderr.count("\n") == 1 and run.stderr.startswith(f"{prog}: error: "), (tool, run.stderr)
        assert run.stderr.count("error:") == 1 and run.stderr.count(prog) == 1, (tool, run.stderr)


@pytest.mark.parametrize("cmd", [["mcp-conform", "--protocol", "xyz"], ["mcp-node", "--protocol", "xyz", "drone"],
                                 ["mcp-capture", "check", "x.mcap", "--protocol", "xyz"],
                                 ["mcp-capture", "dissector", "--protocol", "xyz"],
                                 [sys.executable, "-m", "mcp_conform.spec", "--protocol", "xyz"]], ids=lambda c: " ".join(c[-4:]))
def test_an_unknown_protocol_is_the_same_line_everywhere(cmd) -> None:
    """``--protocol`` goes through ``spec.profiles.pick``: the same error, naming every protocol."""
    from mcp_conform.spec.profiles import PROFILES

    run = subprocess.run(cmd, capture_output=True, text=True, env=ENV, timeout=120)
    assert run.returncode == 2, run.stderr
    last = run.stderr.splitlines()[-1]
    assert last.endswith(f"error: {'check: ' if 'check' in cmd else 'dissector: ' if 'dissector' in cmd else ''}"
                         f"--protocol: 'xyz' is not one of {', '.join(PROFILES)}"), run.stderr


def test_version_everywhere() -> None:
    from mcp_conform.spec.about import tool_version

    for tool, cmd in COMMANDS.items():
        run = subprocess.run([*cmd, "--version"], capture_output=True, text=True, env=ENV, timeout=120)
        assert run.returncode == 0 and tool_version() in run.stdout, (tool, run.stdout, run.stderr)


def test_verbose_and_quiet_exclude_each_other() -> None:
    cells = next(c for _, names, c, _ in OPTION_ROWS if names[0] == "-v")
    builders = _builders()
    for tool, cell in cells.items():
        if cell == "—":
            continue
        parser = builders[tool]()
        subs = _subparsers(parser)
        targets = [parser] if cell == "✓" and not subs else [subs[n] for n in
                                                             (subs if cell == "✓" else cell.split(", "))]
        for p in targets:
            opts = _options(p)
            assert {"-v", "--verbose", "-q", "--quiet"} <= set(opts), tool
            groups = [g for g in p._mutually_exclusive_groups if opts["-v"] in g._group_actions]
            assert groups and opts["-q"] in groups[0]._group_actions, f"{tool}: -v and -q together"


def test_an_mcp_conform_variable_is_one_line_naming_it() -> None:
    run = subprocess.run(["mcp-conform", "--list"], capture_output=True, text=True, timeout=120,
                         env=dict(ENV, MCP_CONFORM_RTO="abc"))
    assert run.returncode == 2 and run.stderr == "mcp-conform: error: MCP_CONFORM_RTO: 'abc' is not a number of seconds\n"


# ------------------------------------------------------------------ "-": run, not parsed
def test_capture_check_reads_stdin_and_writes_json_to_stdout() -> None:
    data = (GOLDEN / "challenge1.mcap").read_bytes()
    run = subprocess.run(["mcp-capture", "check", "-", "--json", "-"], input=data, capture_output=True,
                         env=ENV, timeout=120)
    assert run.returncode == 0, run.stderr
    doc = json.loads(run.stdout)  # the whole of stdout is the report: the terminal one went to stderr
    assert doc["summary"] and b"Nodes" in run.stderr
    assert not Path("-").exists()


def test_capture_diff_and_show_take_stdin_and_stdout(tmp_path) -> None:
    data = (GOLDEN / "challenge1.mcap").read_bytes()
    run = subprocess.run(["mcp-capture", "diff", str(GOLDEN / "challenge1.mcap"), "-", "--json", "-"], input=data,
                         capture_output=True, env=ENV, timeout=120, cwd=tmp_path)
    assert run.returncode == 0 and json.loads(run.stdout)["summary"]["divergences"] == 0, run.stderr
    run = subprocess.run(["mcp-capture", "show", "-", "--svg", "-", "-q"], input=data, capture_output=True,
                         env=ENV, timeout=120, cwd=tmp_path)
    assert run.returncode == 0 and run.stdout.lstrip().startswith(b"<") and b"</svg>" in run.stdout, run.stderr
    assert not (tmp_path / "-").exists()
    run = subprocess.run(["mcp-capture", "check", "-", "-"], input=data, capture_output=True, env=ENV, timeout=120)
    assert run.returncode == 2 and run.stderr.count(b"\n") == 1


def test_a_trace_diff_is_quiet_with_q_and_its_json_alone_on_stdout_with_json_dash() -> None:
    """``mcp-capture diff`` of a MAVLink trace (and an Nsqd one: the same
    ``captures.trace_tools.run_diff``) writes its report as every command does: nothing with
    ``-q``; on stderr when ``--json -`` puts the document on stdout (docs/grammar.md). Before,
    the report went to stdout whatever was asked, the JSON and the text mixed."""
    tlog = str(ROOT / "tests" / "captures" / "data" / "mavproxy-vehicle.tlog")
    quiet = run_module("captures", ["diff", "--protocol", "mavlink", tlog, tlog, "-q"], timeout=120)
    assert (quiet.returncode, quiet.stdout, quiet.stderr) == (0, "", "")
    dash = run_module("captures", ["diff", "--protocol", "mavlink", tlog, tlog, "--json", "-"], timeout=120)
    assert dash.returncode == 0 and json.loads(dash.stdout)["same"] is True, dash.stdout
    assert dash.stderr.startswith("same: "), dash.stderr


@pytest.mark.parametrize("command", ["check", "show", "diff"])
def test_a_file_without_an_nsqd_connection_is_refused_as_nsqd_in_one_line(command) -> None:
    """``--protocol nsqd`` on a capture with no Nsqd connection in it (an MCP run's) is a
    one-line error, exit 2, as MAVLink's tools refuse a file without a MAVLink frame; before,
    ``check`` said "0 connection(s) ... verdict: OK" and exit 0 (H-trace39b noticed)."""
    mcp = str(GOLDEN / "challenge1.mcap")
    run = run_module("captures", [command, "--protocol", "nsqd", mcp, *([mcp] if command == "diff" else [])],
                     timeout=120)
    assert run.returncode == 2, run.stdout + run.stderr
    assert run.stderr.count("\n") == 1 and "no Nsqd connection in it" in run.stderr, run.stderr
    assert "verdict" not in run.stdout, run.stdout


def test_conform_json_dash_is_stdout(tmp_path) -> None:
    run = subprocess.run(["mcp-conform", "--rto", "abc", "--json", "-"], capture_output=True, text=True,
                         env=ENV, timeout=120, cwd=tmp_path)
    assert run.returncode == 2 and json.loads(run.stdout)["error"] == "--rto: 'abc' is not a number of seconds"
    assert run.stderr.count("\n") == 1 and not (tmp_path / "-").exists()
    run = subprocess.run(["mcp-conform", "--list", "--json", "-"], capture_output=True, text=True,
                         env=ENV, timeout=120, cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout)["tool"]["name"] == "mcp-conform" and "MCP-" in run.stderr
    assert not (tmp_path / "-").exists()


@pytest.mark.parametrize("protocol", ["mcp", "nsqd"])
def test_fuzz_json_dash_is_stdout_and_quiet_has_no_progress(tmp_path, protocol) -> None:
    """mcp-fuzz --json - : the summary document on stdout, the campaign's lines on stderr; -q:
    no status line, the last two lines still there. (A child of the tests' fork server,
    tests/forkserver.py: its own process, stdout and stderr files as a pipe is, no terminal.)"""
    run = run_module("mcp_conform.fuzz", ["--protocol", protocol, "--max-cases", "150", "--duration", "8",
                                          "--status-every", "0.1", "-q", "--json", "-"],
                     env=ENV, timeout=120, cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert summary["cases"] >= 1 and summary["findings"] in ([], 0), summary
    lines = run.stderr.splitlines()
    assert any(" cases in " in ln for ln in lines) and not any(" judged cases/s  findings" in ln for ln in lines), lines
    assert not (tmp_path / "-").exists()
