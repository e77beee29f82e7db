"""Gone (issue 37: one findings store, ``fuzz.findings``); only the name ``captures.nsqd``
still imports, until it reads ``fuzz.findings.read_finding(path, "nsqd")`` itself."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fuzz.findings import read_finding
from spec.profiles import NSQD_PROFILE

__all__ = ["load_stream_finding"]


def load_stream_finding(path: str | Path) -> dict[str, Any]:
    """An Nsqd finding's finding.json document (``fuzz.findings.read_finding``)."""
    return read_finding(path, NSQD_PROFILE.name).to_json()
