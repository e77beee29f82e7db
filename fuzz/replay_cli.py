"""``mcp-fuzz --replay finding-N``: replay a finding's minimal sequence and say whether it
reproduces (exit 1, the finding is there) or not (exit 0); 2 on a bad finding or target, as
every protocol's replay does (``fuzz.replay_core``).

The target is the one given on the command line, else the one the campaign recorded in the
finding (its spawn command, or the embedded default).
"""

from __future__ import annotations

import sys

from mcp_conform.fuzz.config import FuzzConfig
from mcp_conform.fuzz.findings import Finding
from mcp_conform.fuzz.replay import run_sequence
from mcp_conform.fuzz.replay_core import PROG, Replayed, replay_command, verdict
from mcp_conform.fuzz.targets import start_target
from mcp_conform.harness.errors import SetupError

__all__ = ["replay_finding", "reproduce"]


def replay_finding(path: str, cfg: FuzzConfig) -> int:
    def run(f: Finding, datagrams: list[bytes]) -> Replayed | int:
        if cfg.embedded:  # the campaign's own target unless told otherwise
            if f.target.get("mode") == "spawn" and f.target.get("spawn"):
                cfg.spawn = f.target["spawn"]
            cfg.mavlink = cfg.mavlink or bool(f.target.get("mavlink"))
        return _replay(f, datagrams, cfg, PROG)
    return replay_command(path, cfg.protocol, lambda f: [bytes.fromhex(h) for h in f.datagrams], run)


def reproduce(f: Finding, cfg: FuzzConfig, prog: str = PROG) -> int:
    """Replay ``f``'s sequence against ``cfg``'s target: 1 when it reproduces, 0 when not,
    2 when the target cannot be reached (said in one line)."""
    return verdict(f, _replay(f, [bytes.fromhex(h) for h in f.datagrams], cfg, prog), prog)


def _replay(f: Finding, datagrams: list[bytes], cfg: FuzzConfig, prog: str) -> Replayed | int:
    try:
        target = start_target(cfg)
    except SetupError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    try:
        outcome = run_sequence(target, datagrams, pace=f.pace, scenario=f.scenario)
    except SetupError as exc:  # attach mode: the node does not answer before the replay
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    finally:
        target.close()
    same = [x for x in outcome.flaws if x.rule == f.rule]
    if same:
        return Replayed(True, f"{same[0].actual} ({len(datagrams)} datagram(s))")
    return Replayed(False, ", ".join(sorted(outcome.rules())))
