"""``mcp-fuzz --protocol nsqd --replay finding-N``: an Nsqd finding replayed once in a fresh
backend (issue 21), as every protocol's is (``fuzz.replay_core``): its minimal cases, its
stateful program (``fuzz.nsqd_stateful.play_program``) or, for the target's own behaviour,
the baseline that showed it (``fuzz.nsqd_blame.baseline``). Exit 1: it reproduced (the same
signature, ``fuzz.nsqd_oracles.same_finding``); 0: it did not; 2: unreadable, or observed over
a campaign (NSQD-CON-3's connect/close cycles: its conformance case replays it). The steps are
every protocol's (``fuzz.replay_core.replay_fresh``, as MAVLink's: a fresh backend started as
the campaign's, ``fuzz.nsqd_campaign.NsqdPlugin.start``); these are Nsqd's parts of it."""

from __future__ import annotations

from typing import Any

from mcp_conform.fuzz.findings import Finding
from mcp_conform.fuzz.nsqd_backend import Backend, BackendTarget, _replay_kind, _reproduces
from mcp_conform.fuzz.nsqd_mutators import Case, Write
from mcp_conform.fuzz.nsqd_oracles import Signature, same_finding
from mcp_conform.fuzz.replay_core import PROG, Replayed, replay_fresh
from mcp_conform.spec.profiles import NSQD_PROFILE

__all__ = ["declined", "read", "replay_on", "replay_stream_finding"]


def _writes(ws: list[dict[str, Any]]) -> tuple[Write, ...]:
    return tuple(Write(bytes.fromhex(w["hex"]), w.get("end", "")) for w in ws)


def read(f: Finding) -> tuple[Signature, Any, list[Case]]:
    """The finding's signature, its program (or None) and its cases (the minimal writes as one
    case when it kept no cases of their own)."""
    doc = f.to_json()
    sig = Signature(doc["oracle"], doc["kind"], tuple(doc.get("frames", [])), doc["rule"], doc.get("access", ""))
    program = None
    if doc.get("program"):
        from mcp_conform.fuzz.nsqd_player import Op

        program = [Op.from_json(o) for o in doc["program"]]
    expect = tuple(doc["expect"][0]) if doc.get("expect") else ()
    cases = [Case(c["kind"], _writes(c["writes"]), bool(c.get("valid")), c.get("note", ""),
                  probe=bool(c.get("probe", True))) for c in doc.get("cases") or []]
    writes = _writes(doc["writes"])
    if not cases and writes:
        cases = [Case(_replay_kind(sig), writes, bool(expect), sig.kind if expect else "", expect=expect,
                      or_error=bool(doc.get("or_error")), check=bool(expect))]
    return sig, program, cases


def declined(f: Finding, inputs: tuple[Signature, Any, list[Case]], prog: str) -> int | None:
    """A finding observed over a campaign (no input, no program, not the target's own
    behaviour): its line, exit 2 (NSQD-CON-3's conformance case replays it)."""
    sig, program, cases = inputs
    if f.no_input or cases or program is not None:
        return None
    print(f"{prog}: {sig.describe()}: observed over a campaign (connect/close cycles); replay it with "
          "mcp-conform --protocol nsqd --select NSQD-CON-3")
    return 2


def replay_on(target: BackendTarget, f: Finding, inputs: tuple[Signature, Any, list[Case]]) -> Replayed:
    """The finding once on ``target``'s fresh backend: its baseline, its program or its cases."""
    sig, program, cases = inputs
    probe = bool(f.doc.get("probe"))
    if f.no_input:
        from mcp_conform.fuzz.nsqd_blame import baseline

        seen = baseline(target.current, sig, probe=probe)
    elif program is not None:
        from mcp_conform.fuzz.nsqd_stateful import play_program

        seen = play_program(target.current, program)
    else:
        _, target.current, seen = _reproduces(target.current, cases, sig, probe=probe)
    shown = seen is not None and same_finding(seen.signature, sig)
    return Replayed(shown, sig.describe() if shown else seen.signature.describe() if seen else "",
                    " with no input (the target's behaviour)" if f.no_input else "")


def replay_stream_finding(path: str, target: tuple[str, int] | None, spawn: str | None, prog: str = PROG) -> int:
    """Replay a finding (``finding-N/``, its finding.json, repro.mcap or repro.pcap) once in a
    fresh backend: 1 reproduced, 0 not, 2 unreadable."""
    return replay_fresh(path, NSQD_PROFILE.name, read, lambda: Backend(target, spawn).pool, replay_on, declined, prog)
