"""``mcp-fuzz --live [HOST:]PORT`` (issue 24 item 2): the campaign watched while it runs.

The fuzzer's session gets a recorder of no file (``traceio.recorder.McapRecorder(None,
live=...)``) feeding a Foxglove WebSocket server (``traceio.live``): the channels of a
capture, as the runner's ``--live`` serves them — each datagram the fuzzer sends and the
node's answers (``/mcp/tx``, ``/mcp/rx``, ``/mcp/burst``), the autopilot link under
``--mavlink`` (``/mavlink``, ``/vehicle/location``, ``/vehicle/attitude``) — and ``/log``
(``foxglove.Log``) with the campaign's events and verdicts: started (engine, seed), each
confirmed finding with its rule, level and evidence (an error for a MUST, a warning
otherwise), ended with the counts.

One worker's run is served: ``--live`` is refused with ``--jobs`` above 1 (each worker is
a process of its own, with its own node).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from mcp_conform.fuzz.config import FuzzConfig
from mcp_conform.fuzz.findings import Finding, FindingStore

__all__ = ["LIVE_RECORDER", "LiveCampaign", "LiveStore"]

#: ``FuzzConfig.extra`` key of the recorder the session writes to (``fuzz.drone_target``)
LIVE_RECORDER = "live_recorder"
NAME = "mcp-fuzz"


class LiveStore(FindingStore):
    """The campaign's findings, each new one also a line of ``/log``."""

    def __init__(self, out: str | Path | None, replay_args: list[str] | None, recorder: Any) -> None:
        super().__init__(out, replay_args)
        self._recorder = recorder

    def add(self, finding: Finding, traffic: list[tuple[str, int, bytes, tuple[str, int]]] | None = None,
            ) -> Path | None:
        new = finding.key not in self.groups
        path = super().add(finding, traffic)
        if new:
            self._recorder.log(finding_text(finding), "error" if finding.level.upper() == "MUST" else "warning", NAME)
        return path


def finding_text(f: Finding) -> str:
    """A finding as the Log panel shows it: rule, level, what was expected, what happened, why."""
    why = "; ".join(f.evidence[:3])
    return (f"finding {f.rule} ({f.level}) [{f.engine}, {len(f.datagrams)} datagram(s)]: expected {f.expected}; "
            f"actual {f.actual}" + (f" — {why}" if why else ""))


class LiveCampaign:
    """The live server of a campaign and the recorder its session writes to."""

    def __init__(self, cfg: FuzzConfig, host: str, port: int) -> None:
        from mcp_conform.traceio.live import LiveServer
        from mcp_conform.traceio.recorder import FUZZ_RECORDER, McapRecorder

        self.server = LiveServer(host, port, name=NAME)
        self.recorder = McapRecorder(None, library=FUZZ_RECORDER, live=self.server.feed())
        cfg.extra[LIVE_RECORDER] = self.recorder
        print(f"{NAME}: live: {self.server.url} (Foxglove: Open connection, Foxglove WebSocket)",
              file=sys.stderr, flush=True)

    def started(self, cfg: FuzzConfig) -> None:
        limit = (f"{cfg.max_cases} cases" if cfg.max_cases is not None else
                 f"{cfg.duration:g} s" if cfg.duration is not None else "the default duration")
        self.recorder.log(f"campaign started: engine {cfg.engine}, seed {cfg.seed}, role {cfg.role}, "
                          f"{cfg.mode} target, up to {limit}", "info", NAME)

    def ended(self, summary: dict[str, Any]) -> None:
        by_rule = ", ".join(f"{r} x{n}" for r, n in (summary.get("findings_by_rule") or {}).items()) or "none"
        state = "interrupted" if summary.get("interrupted") else "ended"
        level = "error" if summary.get("error") and not summary.get("interrupted") else "info"
        self.recorder.log(f"campaign {state}: {summary.get('cases', 0)} cases, {summary.get('findings', 0)} "
                          f"finding(s): {by_rule}" + (f"; {summary['error']}" if summary.get("error") else ""),
                          level, NAME)

    def close(self) -> None:
        """Stop serving (idempotent): nothing is left listening."""
        self.recorder.close()
        self.server.stop()
