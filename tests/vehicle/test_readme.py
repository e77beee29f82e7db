"""The simulated-vehicle section of docs/guide/vehicle.md (once the README's), run as written
(free ports substituted)."""

from __future__ import annotations

import json
import os
import re
import shlex
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from mcp_conform.vehicle.cli import build_parser
from tests.capturing import free_port, wait_for_port

ROOT = Path(__file__).resolve().parents[2]


def section() -> str:
    text = (ROOT / "docs" / "guide" / "vehicle.md").read_text()
    start = text.index("## The simulated vehicle: a MAVLink peer over TCP and UDP")
    return text[start:text.index("\n## ", start + 10)]


def blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", section(), re.S)


def test_the_commands_parse_and_the_records_have_the_documented_keys() -> None:
    vehicle_cmd = shlex.split(blocks("sh")[0].strip())
    assert vehicle_cmd[0] == "mcp-vehicle"
    build_parser().parse_args(vehicle_cmd[1:])  # exits 2 on a bad option
    c_cmds = blocks("sh")[1].splitlines()
    assert build_parser().parse_args(shlex.split(c_cmds[1].split("&")[0])[1:]).no_tcp
    from mcp_conform.vehicle.records import REQUESTS

    for line in blocks("json")[0].splitlines():
        rec = json.loads(line)
        assert rec["request"] in REQUESTS and rec["result"] in ("accepted", "denied")


@pytest.mark.slow
def test_the_vehicle_command_and_each_url_of_the_table(tmp_path: Path) -> None:
    tcp, out, udp_in = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_DGRAM)
    cmd = (blocks("sh")[0].strip().replace("5760", str(tcp)).replace("14550", str(out))
           .replace("14551", str(udp_in)))
    argv = [sys.executable, "-m", "mcp_conform.vehicle", *shlex.split(cmd)[1:]]  # mcp-vehicle, from this tree
    proc = subprocess.Popen(argv, cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        assert wait_for_port(tcp), "the vehicle did not listen on TCP within 10 s"
        snippet = blocks("python")[0]
        for url in ("udpin:127.0.0.1:14550", "tcp:127.0.0.1:5760", "udpout:127.0.0.1:14551"):
            assert url in snippet
            real = url.replace("5760", str(tcp)).replace("14550", str(out)).replace("14551", str(udp_in))
            code = snippet.replace('"udpin:127.0.0.1:14550"', repr(real))
            res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                                 timeout=30)
            assert res.returncode == 0 and "HEARTBEAT" in res.stdout, (url, res.stdout, res.stderr)
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=10)
    assert proc.returncode == 143, err  # SIGTERM: docs/grammar.md
    assert (tmp_path / "requests.jsonl").exists()


def test_help_documents_where_the_vehicle_differs_from_arducopter() -> None:
    text = build_parser().format_help()
    for needle in ("Where it differs from ArduCopter", "MISSION_REQUEST", "Unrequested items are REFUSED",
                   "MAV_MISSION_INVALID_PARAM5_X", "--udp-out", "--udp-in", "--record", "MAVLink 1"):
        assert needle in text, needle


@pytest.mark.parametrize("args", [["--udp-out", "nowhere"], ["--udp-in", "127.0.0.1:99999"],
                                  ["--no-tcp"]])
def test_bad_udp_options_are_one_line_errors(args: list[str], capsys: pytest.CaptureFixture) -> None:
    from mcp_conform.vehicle.cli import main

    with pytest.raises(SystemExit) as exc:
        main(args)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "error:" in err, err
