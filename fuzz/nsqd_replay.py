"""``mcp-fuzz --protocol nsqd --replay finding-N``: an Nsqd finding replayed once in a fresh
backend (issue 21), read as every finding is (``fuzz.findings.read_finding``): its minimal
cases, its stateful program (``fuzz.nsqd_stateful.play_program``) or, for the target's own
behaviour, the baseline that showed it (``fuzz.nsqd_blame.baseline``). Exit 1: it
reproduced (the same signature, ``fuzz.nsqd_oracles.same_finding``); 0: it did not; 2:
unreadable."""

from __future__ import annotations

from typing import Any

from mcp_conform.fuzz.findings import read_finding
from mcp_conform.fuzz.nsqd_backend import Backend, _replay_kind, _reproduces
from mcp_conform.fuzz.nsqd_mutators import Case, Write
from mcp_conform.fuzz.nsqd_oracles import Signature, same_finding
from mcp_conform.spec.profiles import NSQD_PROFILE

__all__ = ["replay_stream_finding"]


def replay_stream_finding(path: str, target: tuple[str, int] | None, spawn: str | None,
                          prog: str = "mcp-fuzz") -> int:
    """Replay a finding (``finding-N/``, its finding.json, repro.mcap or repro.pcap) once in a
    fresh backend: 1 reproduced, 0 not, 2 unreadable."""
    doc_path = path
    try:
        doc = read_finding(path, NSQD_PROFILE.name).to_json()
        writes = [Write(bytes.fromhex(w["hex"]), w.get("end", "")) for w in doc["writes"]]
        expect = tuple(doc.get("expect", [[]])[0]) if doc.get("expect") else ()
        sig = Signature(doc["oracle"], doc["kind"], tuple(doc.get("frames", [])), doc["rule"], doc.get("access", ""))
        program = None
        if doc.get("program"):
            from mcp_conform.fuzz.nsqd_stateful import Op

            program = [Op.from_json(o) for o in doc["program"]]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        print(f"{prog}: error: {'--replay: ' if prog == 'mcp-fuzz' else ''}cannot read {doc_path}: {exc}")
        return 2
    if doc.get("no_input"):
        from mcp_conform.fuzz.nsqd_blame import baseline

        backend = Backend(target, spawn)
        try:
            seen = baseline(backend, sig, probe=bool(doc.get("probe")))
        finally:
            backend.close()
        return _replay_verdict(seen, sig, " with no input")
    if not writes and program is None:
        print(f"{prog}: {sig.describe()}: observed over a campaign (connect/close cycles); replay it with "
              "mcp-conform --protocol nsqd --select NSQD-CON-3")
        return 2
    backend = Backend(target, spawn)
    if program is not None:
        from mcp_conform.fuzz.nsqd_stateful import play_program

        try:
            seen = play_program(backend, program)
        finally:
            backend.close()
        return _replay_verdict(seen, sig)
    try:
        cases = [Case(c["kind"], tuple(Write(bytes.fromhex(w["hex"]), w.get("end", "")) for w in c["writes"]),
                      bool(c.get("valid")), c.get("note", ""), probe=bool(c.get("probe", True)))
                 for c in doc.get("cases") or []]
        cases = cases or [Case(_replay_kind(sig), tuple(writes), bool(expect), sig.kind if expect else "",
                               expect=expect, or_error=bool(doc.get("or_error")), check=bool(expect))]
        ok, backend, hit = _reproduces(backend, cases, sig, probe=bool(doc.get("probe")))
    finally:
        backend.close()
    if ok:
        print(f"reproduced {sig.rule}: {sig.describe()}")
        return 1
    print(f"did not reproduce {sig.describe()}" + (f" (saw {hit.signature.describe()})" if hit else ""))
    return 0


def _replay_verdict(seen: Any, sig: Signature, how: str = "") -> int:
    """A replay's line and exit code: 1 when what it saw is the finding's signature (``how``:
    " with no input" for the target's own behaviour), else 0."""
    if seen is not None and same_finding(seen.signature, sig):
        what = " (the target's behaviour)" if how else ""
        print(f"reproduced {sig.rule}{how}{what}: {sig.describe()}")
        return 1
    print(f"did not reproduce {sig.describe()}{how}" + (f" (saw {seen.signature.describe()})" if seen else ""))
    return 0
