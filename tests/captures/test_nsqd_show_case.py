"""``mcp-capture show --case ID`` of an Nsqd capture (a stream protocol's show,
``captures.stream_tools.run_show``): the records within the case's marks, as MCP's and MAVLink's
show give; an ID that names no case is a one-line usage error (exit 2). Before, ``--case`` was
not looked at: every record was shown, an unknown case's too."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.forkserver import run_module

pytestmark = pytest.mark.slow

CASE = "MSG/test_update_stream_keeps_its_period"


def _shown(proc) -> list[str]:
    return [ln for ln in proc.stdout.splitlines() if ln.startswith("+")]


def test_show_case_of_an_nsqd_capture(tmp_path: Path) -> None:
    cap = tmp_path / "n.mcap"
    run = run_module("conformance", ["--protocol", "nsqd", "--capture", str(cap), "--select", "MSG/test_update"],
                     timeout=120)
    assert run.returncode == 0 and cap.exists(), run.stdout[-2000:] + run.stderr[-2000:]
    whole = run_module("captures", ["show", str(cap)])
    case = run_module("captures", ["show", str(cap), "--case", CASE])
    assert whole.returncode == 0 and case.returncode == 0, whole.stderr + case.stderr
    every, within = _shown(whole), _shown(case)
    # the run's first connection (the startup's liveness check) is before the case's start mark
    assert within and len(within) < len(every), (len(within), len(every))
    assert not any(" conn 1 " in ln for ln in within) and any(" conn 1 " in ln for ln in every)
    assert {ln.split("s ", 1)[1] for ln in within} <= {ln.split("s ", 1)[1] for ln in every}
    nope = run_module("captures", ["show", str(cap), "--case", "NOPE"])
    assert nope.returncode == 2 and nope.stdout.count("\n") <= 1, nope.stdout
    assert nope.stderr.strip().splitlines() == [f"mcp-capture: error: --case: 'NOPE': {cap} is not a case of it"]
