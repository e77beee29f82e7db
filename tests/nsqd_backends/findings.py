"""The finding of a short seeded ``mcp-fuzz --protocol nsqd`` campaign against a fault of the C
backend (tests/nsqd_backends), made once per test session and shared by the tests that read it.

tests/fuzz/test_nsqd_fuzz.py (each class of issue 21 found, confirmed and replayed) and
tests/fuzz/test_nsqd_repro.py (a finding's repro.mcap and repro.pcap) ran the same campaign
(crash-on-negative-string, seed 20140307, 90 s, stopped at its first confirmed finding) each
on its own; :func:`class_finding` runs it once (``tests.xdist_once.once`` across pytest-xdist
workers, a dict within one process) and gives each what it asserts on. Its files are shared:
read-only (copy them to change them).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from tests.xdist_once import once

#: The campaign's seed and time limit (it stops at its first confirmed finding).
SEED, DURATION = 20140307, 90.0

_MADE: dict[str, dict[str, Any]] = {}


def spawn(exe: Path, fault: str | None = None) -> str:
    """The C backend's command for the fuzzer, at a 0.1 s UPDATE period."""
    return f"{exe} --host {{target_host}} --port {{target_port}} --update-period 0.1" + (f" --fault {fault}" if fault else "")


def class_finding(tmp_path_factory: pytest.TempPathFactory, exe: Path, fault: str) -> dict[str, Any]:
    """The campaign against ``fault``: ``dir`` (its output directory), ``oracles`` and
    ``rules`` (of its confirmed findings, in order) and ``summary`` (its summary)."""
    if fault not in _MADE:
        from mcp_conform.fuzz.nsqd_campaign import StreamCampaign

        def campaign(out: Path) -> dict[str, Any]:
            c = StreamCampaign(None, spawn(exe, fault), SEED, DURATION, None, out, stop_after=1)
            summary = c.run()
            return {"dir": out, "oracles": [f.signature.oracle for f in c.findings],
                    "rules": [f.signature.rule for f in c.findings], "summary": summary}

        _MADE[fault] = once(tmp_path_factory, f"nsqd-class-{fault}", campaign)
    return _MADE[fault]
