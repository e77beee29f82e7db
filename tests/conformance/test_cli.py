"""mcp-conform's front end: argument errors, --role manager, --list, --version, exit codes."""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from mcp_conform.conformance.cli import build_parser, main, pytest_args
from mcp_conform.conformance.report import validate_json
from tests.capturing import free_port
from tests.forkserver import run_module

ROOT = Path(__file__).resolve().parents[2]


def conform(*args: str, cwd: Path = ROOT, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT), NO_COLOR="1")
    return run_module("conformance", list(args), cwd=cwd, env=env, timeout=timeout)


def report(path: Path) -> dict:
    doc = json.loads(path.read_text())
    validate_json(doc)
    return doc


@pytest.mark.parametrize(("args", "needle"), [
    (["--rto", "abc"], "--rto: 'abc' is not a number of seconds"),
    (["--ack-window", "-1"], "--ack-window"),
    (["--timeout", "0"], "--timeout"),
    (["--target", "localhost"], "--target"),
    (["--target", "127.0.0.1:70000"], "--target: port 70000 is out of range"),
    (["--listen", "x:y"], "--listen"),
    (["--target-id", "65536"], "--target-id: 65536 is out of range"),
    (["--broadcast-id", "many"], "--broadcast-id"),
    (["--seed", "1.5"], "--seed"),
    (["--role", "pilot"], "--role: 'pilot' is not a role of --protocol mcp (drone, manager)"),
    (["--spawn", "  "], "--spawn: the command is empty"),
    (["--bogus"], "unrecognized arguments: --bogus"),
    (["--rto"], "argument --rto: expected one argument"),
    (["--capture", "/nonexistent-dir/x.mcap"], "--capture: directory"),
    (["--mavlink1"], "--mavlink1: the runner speaks MAVLink 1 only as the vehicle of --protocol mavlink --role gcs, "
                     "not with --protocol mcp --role drone"),
])
def test_bad_arguments_exit_2_with_one_line_and_json(tmp_path, args, needle):
    path = tmp_path / "r.json"
    proc = conform(*args, "--json", str(path))
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("mcp-conform: error: ") and needle in lines[0], proc.stderr
    assert "Traceback" not in proc.stdout + proc.stderr
    doc = report(path)
    assert needle in doc["error"] and doc["cases"] == []


def test_json_path_with_equals_sign_is_honoured_on_argparse_errors(tmp_path):
    path = tmp_path / "r.json"
    proc = conform("--nope", f"--json={path}")
    assert proc.returncode == 2 and report(path)["error"].startswith("unrecognized arguments")


@pytest.mark.parametrize("args,needle", [
    (("--drones", "1,x"), "--drones"), (("--drones", "1,1"), "--drones"), (("--drones", "0"), "--drones"),
    (("--challenge", "4"), "--challenge"), (("--waypoints", "/nonexistent/wp.txt"), "--waypoints"),
])
def test_manager_role_options_are_checked(tmp_path, args, needle):
    path = tmp_path / "r.json"
    proc = conform("--role", "manager", *args, "--json", str(path))
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.startswith(f"mcp-conform: error: {needle}"), proc.stderr
    doc = report(path)
    assert doc["role"] == "manager" and needle in doc["error"]


def test_manager_role_lists_its_own_cases(tmp_path):
    proc = conform("--role", "manager", "--list", cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "BLK/test_nothing_before_every_mission_ready  MCP-BLK-2  MUST" in proc.stdout
    assert "test_mission_ready_is_unicast_to_the_manager" not in proc.stdout  # a drone case


def test_list_touches_nothing(tmp_path):
    marker = tmp_path / "spawned"
    spawn = f"{shlex.quote(sys.executable)} -c 'open({str(marker)!r}, \"w\")'"
    path = tmp_path / "r.json"
    proc = conform("--list", "--spawn", spawn, "--json", str(path), cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    out = proc.stdout
    assert "ACK/test_broadcast_is_not_acked  MCP-ACK-4  MUST" in out
    assert "cases" in out.splitlines()[-1]
    assert not marker.exists()  # no node was started
    assert report(path)["cases"] == []
    assert "pytest" not in out.lower() and "passed" not in out  # one tool, not pytest's chatter
    assert not (tmp_path / ".pytest_cache").exists()


def test_list_with_select(tmp_path):
    proc = conform("--list", "--select", "MCP-HDR", "ACK/test_broadcast", cwd=tmp_path)
    assert proc.returncode == 0
    ids = [ln.split()[0] for ln in proc.stdout.splitlines()[:-1]]
    assert ids and all(i.startswith(("HDR/", "ACK/test_broadcast")) for i in ids)
    assert "ACK/test_broadcast_is_not_acked" in ids


def test_a_conftest_in_the_working_directory_takes_no_part(tmp_path):
    """The cases are named by package, so pytest would load the working directory's
    ``test*/conftest.py`` into the run: a user's own test hooks (here one that raises at import)
    broke ``mcp-conform`` run from their project. ``--noconftest`` keeps the run isolated."""
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "conftest.py").write_text('raise RuntimeError("the user\'s conftest was loaded")\n')
    proc = conform("--list", "--select", "MCP-HDR", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "conftest" not in proc.stderr and proc.stdout.splitlines()[0].startswith("HDR/")


def test_select_matching_nothing_is_exit_2(tmp_path):
    path = tmp_path / "r.json"
    proc = conform("--select", "MCP-NOPE", "--json", str(path), cwd=tmp_path)
    assert proc.returncode == 2
    assert report(path)["error"] == "--select: no case matches MCP-NOPE"
    assert "--select: no case matches MCP-NOPE" in proc.stderr


def test_exclude_matching_nothing_is_exit_2_as_select(tmp_path):
    """Issue 18 item 16: an --exclude that matches no case (a typo) says so, as --select does."""
    path = tmp_path / "r.json"
    proc = conform("--exclude", "MCP-ACK-4", "MCP-NOPE", "--json", str(path), cwd=tmp_path)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert report(path)["error"] == "--exclude: no case matches MCP-NOPE"
    assert "--exclude: no case matches MCP-NOPE" in proc.stderr


def test_target_that_never_answers_is_a_setup_error(tmp_path):
    path = tmp_path / "r.json"
    proc = conform("--target", f"127.0.0.1:{free_port()}", "--listen", f"127.0.0.1:{free_port()}",
                   "--rto", "0.1", "--ack-window", "0.1", "--json", str(path), cwd=tmp_path)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    doc = report(path)
    assert doc["error"] and "answer" in doc["error"]
    assert doc["error"] in proc.stderr and doc["error"] not in proc.stdout  # errors go to stderr
    assert "Traceback" not in proc.stdout + proc.stderr


def test_a_silent_target_is_waited_for_visibly_and_briefly(tmp_path):
    """Issue 18 item 14: attaching to a silent target says what the run waits for (a plain
    line off a terminal), waits --startup-timeout (default 60 s, not the run's 600 s) for the
    node's first datagram, then exits 2 with one line."""
    path = tmp_path / "r.json"
    listen = free_port()
    proc = conform("--target", f"127.0.0.1:{free_port()}", "--listen", f"127.0.0.1:{listen}",
                   "--startup-timeout", "2", "--json", str(path), cwd=tmp_path)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert (f"waiting for the node's first datagram (its Mission_Ready, or an ACK of a probe) on "
            f"127.0.0.1:{listen} (up to 2 s)") in proc.stdout
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "--startup-timeout: no datagram from the node within 2 s" in lines[0], proc.stderr
    assert report(path)["error"].startswith("--startup-timeout: no datagram from the node within 2 s")
    assert "--startup-timeout S" in build_parser().format_help() and "(default 60" in build_parser().format_help()
    from mcp_conform.conformance.options import make_config

    assert make_config({}).extra["startup_timeout"] == 60.0


def test_version():
    proc = conform("--version")
    assert proc.returncode == 0 and proc.stdout.startswith("mcp-conform ")


def test_main_in_process_returns_2_for_bad_args(capsys):
    assert main(["--strict", "--rto", "x"]) == 2
    assert capsys.readouterr().err.count("\n") == 1


@pytest.mark.parametrize(("protocol", "role"), [("mavlink", "vehicle"), ("nsqd", "backend"), ("mcp", "manager")])
def test_mavlink1_is_the_gcs_role_s_alone(tmp_path, protocol, role):
    """--mavlink1 where the runner plays no MAVLink vehicle: one line naming the role that takes it,
    exit 2, the error in the JSON report (not schema-checked: report.schema.json knows MCP and
    Nsqd's error reports only)."""
    path = tmp_path / "r.json"
    proc = conform("--protocol", protocol, "--role", role, "--mavlink1", "--json", str(path))
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    line = ("--mavlink1: the runner speaks MAVLink 1 only as the vehicle of --protocol mavlink --role gcs, "
            f"not with --protocol {protocol} --role {role}")
    assert proc.stderr == f"mcp-conform: error: {line}\n"
    assert json.loads(path.read_text())["error"] == line


MAVLINK_ROLES = "--protocol mcp --role drone or --protocol mavlink --role vehicle or --protocol mavlink --role gcs"


@pytest.mark.parametrize(("protocol", "role", "value"), [("mcp", "manager", None), ("mcp", "manager", "udp"),
                                                         ("nsqd", "backend", None)])
def test_mavlink_in_a_role_without_a_mavlink_link_is_one_line(tmp_path, protocol, role, value):
    """--role manager took --mavlink and ignored it (no vehicle, {mavlink} empty, no word said):
    as --mavlink1, one line naming the roles that take it, exit 2, the error in the JSON report."""
    path = tmp_path / "r.json"
    proc = conform("--protocol", protocol, "--role", role, "--mavlink", *([value] if value else []), "--json", str(path))
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    line = (f"--mavlink: the runner starts or chooses a MAVLink link only with {MAVLINK_ROLES}, "
            f"not with --protocol {protocol} --role {role}")
    assert proc.stderr == f"mcp-conform: error: {line}\n"
    assert json.loads(path.read_text())["error"] == line


def test_mavlink_is_checked_from_the_environment_and_kept_where_a_role_takes_it(tmp_path):
    """MCP_CONFORM_MAVLINK is --mavlink: the manager role names the variable; the roles with a
    MAVLink link still take it (their case lists)."""
    from mcp_conform.conformance.options import make_config

    env = dict(os.environ, PYTHONPATH=str(ROOT), NO_COLOR="1", MCP_CONFORM_MAVLINK="udp")
    proc = run_module("conformance", ["--role", "manager", "--list"], cwd=tmp_path, env=env, timeout=120)
    assert proc.returncode == 2 and proc.stderr.startswith(
        "mcp-conform: error: MCP_CONFORM_MAVLINK: the runner starts or chooses a MAVLink link only with "), proc.stderr
    for protocol, role in (("mcp", "drone"), ("mavlink", "vehicle"), ("mavlink", "gcs")):
        cfg = make_config({"protocol": protocol, "role": role, "mavlink": "udp"})
        assert cfg.mavlink and cfg.mavlink_transport == "udp", (protocol, role)


def test_mavlink1_from_the_environment_is_checked_as_the_option(tmp_path):
    """MCP_CONFORM_MAVLINK1 is --mavlink1: a role without it is the one line naming the variable;
    the gcs role takes it, and the runner's pytest options carry it."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), NO_COLOR="1", MCP_CONFORM_MAVLINK1="1")
    proc = run_module("conformance", ["--protocol", "mavlink", "--list"], cwd=tmp_path, env=env, timeout=120)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert proc.stderr.startswith("mcp-conform: error: MCP_CONFORM_MAVLINK1: the runner speaks MAVLink 1 only"), proc.stderr
    proc = run_module("conformance", ["--protocol", "mavlink", "--role", "gcs", "--list"], cwd=tmp_path, env=env,
                      timeout=120)
    assert proc.returncode == 0 and "MAV-HB-2" in proc.stdout, proc.stderr
    ns = build_parser().parse_args(["--protocol", "mavlink", "--role", "gcs", "--mavlink", "udp", "--mavlink1"])
    args = pytest_args(ns)
    assert "--mcp-mavlink1" in args and "--mcp-mavlink=udp" in args
    assert "--mcp-mavlink1" not in pytest_args(build_parser().parse_args(["--protocol", "mavlink", "--role", "gcs"]))


def test_pytest_args_are_a_quiet_isolated_run():
    ns = build_parser().parse_args(["--target", "127.0.0.1:7890", "--select", "ACK", "HDR", "--strict",
                                    "--rto", "0.5"])
    args = pytest_args(ns)
    assert args[-2:] == ["--pyargs", "mcp_conform.conformance.cases"]
    for pair in (["-p", "no:cacheprovider"], ["-p", "no:randomly"], ["-p", "no:terminal"]):
        assert any(args[i:i + 2] == pair for i in range(len(args)))
    assert "--mcp-target=127.0.0.1:7890" in args and "--mcp-strict" in args and "--mcp-rto=0.5" in args
    assert args.count("--mcp-select=ACK") == 1 and "--mcp-select=HDR" in args
    assert "--mcp-frontend" in args


def test_sigterm_leaves_valid_reports(tmp_path):
    """An interrupted run still writes its JSON (exit 128 + 15, the grammar's) and a readable capture."""
    import signal

    from mcap.reader import make_reader

    js, cap = tmp_path / "r.json", tmp_path / "run.mcap"
    env = dict(os.environ, PYTHONPATH=str(ROOT), NO_COLOR="1", PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "mcp_conform.conformance", "--json", str(js), "--capture", str(cap)],
                            cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert proc.stdout is not None
        seen = []
        for line in proc.stdout:
            seen.append(line)
            if line.startswith(("PASSED", "FAILED", "INFO", "SKIPPED", "WARNED", "ERROR")):
                break
        proc.send_signal(signal.SIGTERM)
        rest, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 143, "".join(seen) + rest
    doc = report(js)
    assert doc["error"] == "interrupted by SIGTERM" and doc["cases"]
    with open(cap, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        topics = [ch.topic for _, ch, _ in reader.iter_messages()]
    assert "/conformance/case" in topics and "/mcp/rx" in topics
