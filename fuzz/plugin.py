"""What ``mcp-fuzz`` needs of a protocol's campaign (issue 37: the protocol a plug-in).

A protocol's profile (``spec.profiles``, ``fuzz_campaign``) names a class that satisfies
:class:`FuzzCampaign`; ``fuzz.cli`` runs every protocol's through it, with one store of
findings (``fuzz.findings``), one live display (``fuzz.progress``), one ``--jobs``
parent (``fuzz.workers``) and one campaign loop (``fuzz.loop``, over the protocol's
``fuzz.loop.Plugin``): MCP's is ``fuzz.campaign.DatagramCampaign``, Nsqd's
``fuzz.nsqd_campaign.StreamCampaign``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

from mcp_conform.fuzz.config import FuzzConfig
from mcp_conform.fuzz.findings import FindingStore
from mcp_conform.fuzz.progress import LiveProgress, Progress

__all__ = ["FuzzCampaign"]


class FuzzCampaign(Protocol):
    """What ``mcp-fuzz`` needs of a protocol's campaign (the profile's ``fuzz_campaign``,
    ``spec.profiles``): the one command line runs every protocol's through it (``fuzz.cli``)."""

    #: the options of ``mcp-fuzz`` this campaign does not take (a one-line usage error)
    REFUSED: tuple[str, ...]
    store: FindingStore

    @classmethod
    def from_config(cls, cfg: FuzzConfig, tick: Callable[[Progress], None] | None) -> FuzzCampaign:
        """The campaign ``cfg`` asks for; ``tick``: its live progress. SetupError: it cannot start."""

    def fuzz(self) -> dict[str, Any]:
        """The whole campaign (``--jobs`` workers included) until its budget, a stop or SIGINT
        (ended with what it has: ``"interrupted": true``); its summary, summary.json written."""

    def abort(self) -> None:
        """After an error or a second SIGINT: summary.json of what it has, written."""

    def final(self, summary: dict[str, Any], live: LiveProgress, strict: bool) -> int:
        """The closing lines (findings, summary, where the time went); the exit code."""

    @staticmethod
    def replay(path: str, cfg: FuzzConfig) -> int:
        """``--replay``: 1 reproduced, 0 not, 2 unreadable or no target."""
