"""``mcp-fuzz --protocol nsqd --replay finding-N``: an Nsqd finding replayed once in a fresh
backend (issue 21), as every protocol's is (``fuzz.replay_core``): its minimal cases, its
stateful program (``fuzz.nsqd_stateful.play_program``) or, for the target's own behaviour,
the baseline that showed it (``fuzz.nsqd_blame.baseline``). Exit 1: it reproduced (the same
signature, ``fuzz.nsqd_oracles.same_finding``); 0: it did not; 2: unreadable, or observed over
a campaign (NSQD-CON-3's connect/close cycles: its conformance case replays it)."""

from __future__ import annotations

from typing import Any

from mcp_conform.fuzz.findings import Finding
from mcp_conform.fuzz.nsqd_backend import Backend, _replay_kind, _reproduces
from mcp_conform.fuzz.nsqd_mutators import Case, Write
from mcp_conform.fuzz.nsqd_oracles import Signature, same_finding
from mcp_conform.fuzz.replay_core import PROG, Replayed, replay_command
from mcp_conform.spec.profiles import NSQD_PROFILE

__all__ = ["replay_stream_finding"]


def _writes(ws: list[dict[str, Any]]) -> tuple[Write, ...]:
    return tuple(Write(bytes.fromhex(w["hex"]), w.get("end", "")) for w in ws)


def _read(f: Finding) -> tuple[Signature, Any, list[Case]]:
    """The finding's signature, its program (or None) and its cases (the minimal writes as one
    case when it kept no cases of their own)."""
    doc = f.to_json()
    sig = Signature(doc["oracle"], doc["kind"], tuple(doc.get("frames", [])), doc["rule"], doc.get("access", ""))
    program = None
    if doc.get("program"):
        from mcp_conform.fuzz.nsqd_stateful import Op

        program = [Op.from_json(o) for o in doc["program"]]
    expect = tuple(doc["expect"][0]) if doc.get("expect") else ()
    cases = [Case(c["kind"], _writes(c["writes"]), bool(c.get("valid")), c.get("note", ""),
                  probe=bool(c.get("probe", True))) for c in doc.get("cases") or []]
    writes = _writes(doc["writes"])
    if not cases and writes:
        cases = [Case(_replay_kind(sig), writes, bool(expect), sig.kind if expect else "", expect=expect,
                      or_error=bool(doc.get("or_error")), check=bool(expect))]
    return sig, program, cases


def replay_stream_finding(path: str, target: tuple[str, int] | None, spawn: str | None, prog: str = PROG) -> int:
    """Replay a finding (``finding-N/``, its finding.json, repro.mcap or repro.pcap) once in a
    fresh backend: 1 reproduced, 0 not, 2 unreadable."""
    def run(f: Finding, read: tuple[Signature, Any, list[Case]]) -> Replayed | int:
        sig, program, cases = read
        if not f.no_input and not cases and program is None:
            print(f"{prog}: {sig.describe()}: observed over a campaign (connect/close cycles); replay it with "
                  "mcp-conform --protocol nsqd --select NSQD-CON-3")
            return 2
        probe = bool(f.doc.get("probe"))
        backend = Backend(target, spawn)
        try:
            if f.no_input:
                from mcp_conform.fuzz.nsqd_blame import baseline

                seen = baseline(backend, sig, probe=probe)
            elif program is not None:
                from mcp_conform.fuzz.nsqd_stateful import play_program

                seen = play_program(backend, program)
            else:
                _, backend, seen = _reproduces(backend, cases, sig, probe=probe)
        finally:
            backend.close()
        shown = seen is not None and same_finding(seen.signature, sig)
        return Replayed(shown, sig.describe() if shown else seen.signature.describe() if seen else "",
                        " with no input (the target's behaviour)" if f.no_input else "")
    return replay_command(path, NSQD_PROFILE.name, _read, run, prog)
