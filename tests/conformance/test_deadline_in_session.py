"""The run's --timeout falling while the runner makes its session, before the node's startup
begins (its recorder, its sockets, the modules it imports), is a setup error: exit 2, one line
naming the --timeout, no case run; never each case an error. CI run 50 (a fresh clone beside
other jobs, load ~11): ``test_faults::test_bad_addresses_are_setup_errors[--timeout of 3 s]``
got 44 cases in error, "run deadline exceeded", the SIGALRM of the run's deadline having struck
in the session's making, outside the startup's own handler (``conformance._run_state``).

In-process, as the simulator runs the suite: a plugin's ``pytest_mcp_make_session`` takes
longer than the run's --timeout, as a loaded host did."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from mcp_conform.conformance import cli
from mcp_conform.spec.profiles import pick
from tests.capturing import free_port


class _SlowToMake:
    """The session's making outlasts the run's --timeout (the next implementation makes it)."""

    @pytest.hookimpl(tryfirst=True)
    def pytest_mcp_make_session(self, cfg, recorder, config):  # type: ignore[no-untyped-def]
        end = time.monotonic() + 2.5
        while time.monotonic() < end:  # the run deadline's SIGALRM strikes in here
            time.sleep(0.05)


def test_the_run_deadline_while_the_session_is_made_is_a_setup_error(tmp_path: Path) -> None:
    path = tmp_path / "r.json"
    argv = ["--target", f"127.0.0.1:{free_port()}", "--listen", "127.0.0.1:0", "--timeout", "1",
            "--json", str(path), "--quiet"]
    ns = cli.build_parser().parse_args(argv)
    ns.protocol, ns.role = (p.name for p in pick("mcp", "drone"))
    with cli._quiet(True):
        rc = cli.run_pytest(cli.pytest_args(ns), [_SlowToMake()])
    doc = json.loads(path.read_text())
    assert rc == 2 and doc["cases"] == [], (rc, doc.get("error"), [c["reason"] for c in doc["cases"]][:3])
    assert "--timeout of 1 s" in doc["error"], doc["error"]
