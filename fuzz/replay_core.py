"""``mcp-fuzz --protocol NAME --replay finding-N`` for every protocol (issue 39: a protocol's
plumbing near zero), written once: a protocol's replay (MCP's ``fuzz.replay_cli``, MAVLink's
``fuzz.mavlink_campaign``, Nsqd's ``fuzz.nsqd_replay``) declares only what is its own -- what a
finding holds to replay (``read``) and how it is replayed on a fresh target (``run``).

The shape is every protocol's: the finding read as every finding is
(``fuzz.findings.read_finding``: its ``finding-N/``, its finding.json or its repro file; an
error reading it, or what it holds, is one line and exit 2); replayed once on the target
``--spawn``/``--target`` name (or the protocol's default); one line says whether it
reproduced, and the exit code: 1 it did (the finding is there), 0 it did not (what the replay
saw instead, if anything). A protocol may decline a finding its replay cannot show (its own
line and exit code: ``run`` returns an ``int``). A stream or link protocol's (MAVLink's, Nsqd's:
:func:`replay_fresh`) replays on a fresh target it starts as its campaign does, closed after.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

from mcp_conform.fuzz.findings import Finding, read_finding

__all__ = ["PROG", "Replayed", "replay_command", "replay_fresh", "verdict"]

PROG = "mcp-fuzz"
I = TypeVar("I")  # noqa: E741 - what a finding holds to replay


@dataclass(frozen=True)
class Replayed:
    """What one replay showed: ``shown`` (the finding's own signature), ``actual`` (what it
    showed, or saw instead; empty: nothing), ``how`` (words after the rule, e.g. " with no
    input" for the target's own behaviour)."""

    shown: bool
    actual: str = ""
    how: str = ""


def replay_command(path: str, protocol: str, read: Callable[[Finding], I],
                   run: Callable[[Finding, I], Replayed | int], prog: str = PROG) -> int:
    """``--replay path``: the finding of ``protocol`` read (``read(f)``: what it holds to
    replay; ``ValueError``, ``KeyError``, ``TypeError``: unreadable, exit 2), replayed
    (``run(f, inputs)``: what it showed, or an exit code when the protocol declines it, its line
    said), its line printed (:func:`verdict`); 1 reproduced, 0 not, 2 unreadable."""
    opt = "--replay: " if prog == PROG else ""
    try:
        f = read_finding(path, protocol)
    except ValueError as exc:
        print(f"{prog}: error: {opt}{exc}", file=sys.stderr)
        return 2
    try:
        inputs = read(f)
    except (ValueError, KeyError, TypeError) as exc:
        print(f"{prog}: error: {opt}cannot read {path}: {exc!r}", file=sys.stderr)
        return 2
    return verdict(f, run(f, inputs), prog)


def replay_fresh(path: str, protocol: str, read: Callable[[Finding], I], start: Callable[[], Any],
                 replay_on: Callable[[Any, Finding, I], Replayed], declined: Callable[[Finding, I, str], int | None],
                 prog: str = PROG) -> int:
    """:func:`replay_command` on a fresh target: unless the protocol declines the finding
    (``declined(f, inputs, prog)``: its line said, its exit code; None: replay it), a target
    started (``start()``: as the campaign's, ``--spawn``/``--target`` or the reference node;
    SetupError: the caller's), what it holds replayed on it (``replay_on(target, f, inputs)``),
    the target closed after."""
    def run(f: Finding, inputs: I) -> Replayed | int:
        said = declined(f, inputs, prog)
        if said is not None:
            return said
        target = start()
        try:
            return replay_on(target, f, inputs)
        finally:
            target.close()
    return replay_command(path, protocol, read, run, prog)


def verdict(f: Finding, r: Replayed | int, prog: str = PROG) -> int:
    """A replay's line and exit code: 1 when it showed ``f`` again, 0 when not (an ``int``:
    a protocol's own, its line said)."""
    if isinstance(r, int):
        return r
    if r.shown:
        print(f"{prog}: reproduced {f.rule}{r.how} ({f.shape}): {r.actual}")
        return 1
    print(f"{prog}: did not reproduce {f.rule}{r.how} ({f.shape})" + (f" (saw {r.actual})" if r.actual else ""))
    return 0
