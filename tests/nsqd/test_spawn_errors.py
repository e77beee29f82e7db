"""A bad ``--spawn`` is the same one-line setup error whatever the protocol (issue 37 item 2:
one node-under-test layer). The Nsqd session once filled ``--spawn`` with ``str.format``
and ``shlex.split`` of its own: a ``{id}`` placeholder raised KeyError, a bad quote was no
setup error and a missing executable's OSError escaped. Both sessions now spawn through
``harness.session_base`` (``fill_placeholders``, ``SpawnedNode``): the same error line, exit 2,
the same words in the JSON report, no traceback."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from tests.forkserver import run_module

ROOT = Path(__file__).resolve().parents[2]


def setup_error(tmp_path: Path, protocol: str, spawn: str) -> tuple[str, dict]:
    """The run's one error line (``error: ...``) and its JSON report."""
    out = tmp_path / f"{protocol}.json"
    env = dict(os.environ, PYTHONPATH=str(ROOT), NO_COLOR="1")
    proc = run_module("conformance", ["--protocol", protocol, "--spawn", spawn, "--timeout", "30",
                                      "--json", str(out)], cwd=tmp_path, env=env, timeout=120)
    text = proc.stdout + proc.stderr
    assert proc.returncode == 2, text
    assert "Traceback" not in text and "KeyError" not in text, text
    errors = [ln for ln in text.splitlines() if "error: " in ln]
    assert len(errors) == 1, text
    return errors[0].split("error: ", 1)[1], json.loads(out.read_text())


@pytest.mark.parametrize(("spawn", "needle"), [
    ("/nonexistent/node {id} {target_port}", "--spawn: cannot start '/nonexistent/node'"),
    ("node 'unterminated {target_port}", "--spawn: cannot split command"),
    ("/nonexistent/node --listen {target_host}:{target_port}", "--spawn: cannot start '/nonexistent/node'"),
])
def test_a_bad_spawn_is_the_same_setup_error_under_both_protocols(tmp_path, spawn, needle):
    mcp_line, mcp_doc = setup_error(tmp_path, "mcp", spawn)
    nsqd_line, nsqd_doc = setup_error(tmp_path, "nsqd", spawn)
    assert needle in nsqd_line and nsqd_line == mcp_line
    assert nsqd_doc["error"] == mcp_doc["error"] and needle in nsqd_doc["error"]
    assert nsqd_doc["role"] == "backend" and nsqd_doc["cases"] == []
