"""Findings, whatever the protocol: confirmed, minimal, grouped, and written where a user can
replay them (issue 37: one ``Finding``, one findings store for MCP and Nsqd alike).

A finding is kept only once it has been confirmed by replays and shrunk to a minimal input
(MCP: ``fuzz.triage`` over ``fuzz.replay``; Nsqd: ``fuzz.nsqd_triage``). Findings of the
same rule and shape (what kind of input, what the node did) are one group: the first is
written, the others are counted. Under ``--out DIR`` each group is ``finding-N/``:

- ``finding.json``: one document for every protocol: protocol, rule, level, rule text,
  expected, actual, evidence, shape, seed, engine, worker, occurrences, the program (stateful
  engines), note, replays, no_input; MCP's input as ``datagrams`` (hex) with its pace and
  scenario, a stream protocol's as its own fields (``doc``: Nsqd's signature, writes, cases);
- the protocol's captures (``repro``: MCP's ``repro.mcap``, :func:`write_repro`; Nsqd's
  ``repro.mcap``, ``repro.pcap`` and input files, ``fuzz.nsqd_repro``);
- ``replay.txt``: the one-line command that replays it (``mcp-fuzz --replay DIR ...``).

``summary.json`` (:func:`write_summary`) is written at the end of every campaign.
"""

from __future__ import annotations

import json
import threading
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from mcp_conform.fuzz.finding_files import (
    finding_dir,
    read_finding_doc,
    write_finding_doc,
    write_packets_repro,
)
from mcp_conform.fuzz.oracles import Flaw
from mcp_conform.spec import RULES
from mcp_conform.spec.profiles import DEFAULT_PROTOCOL, pick

__all__ = ["Finding", "FindingStore", "finding_from_json", "finding_from_metadata", "load_finding",
           "read_finding", "write_summary"]

FINDING_SCHEMA = 1
NO_INPUT = "no input: the node's behaviour whatever it is sent"  # a baseline finding's shape (fuzz.triage)


#: A finding's fields that live only while the campaign runs (not in finding.json).
_RUNTIME = ("doc", "signature", "cases", "traffic")
#: Old finding.json keys read as the new ones (an Nsqd finding written before issue 37).
_OLD_KEYS = {"actual": "detail", "shape": "description", "occurrences": "count"}


@dataclass
class Finding:
    """One confirmed, minimised finding (the representative of its group), of any protocol."""

    rule: str
    expected: str
    actual: str
    datagrams: list[str]  # MCP's input: hex, in sending order (a stream protocol's is in ``doc``)
    shape: str
    engine: str
    seed: int
    pace: str = "batch"
    level: str = ""
    evidence: list[str] = field(default_factory=list)
    worker: int = 0
    occurrences: int = 1
    #: the stateful engine's shortest program (MCP: as hypothesis printed it; Nsqd: its ops)
    program: Any = None
    scenario: str | None = None  # how the node is started before the datagrams (fuzz.replay)
    source: str = ""
    target: dict[str, Any] = field(default_factory=dict)  # how the campaign reached the node
    protocol: str = DEFAULT_PROTOCOL  # its profile's name (``spec.profiles``)
    note: str = ""  # how the input came to be blamed (Nsqd: the case's mutation, a probe after it)
    replays: str = ""  # "N of N": the confirming replays that showed it
    no_input: bool = False  # the target's behaviour: a baseline sent nothing showed it
    #: the protocol's own finding.json fields (Nsqd: its signature, writes, cases, expect)
    doc: dict[str, Any] = field(default_factory=dict)
    signature: Any = None  # a stream protocol's signature (``fuzz.nsqd_oracles.Signature``)
    cases: list[Any] = field(default_factory=list)  # a stream protocol's minimal cases
    traffic: list[Any] = field(default_factory=list)  # a stream protocol's last confirming replay's

    def __post_init__(self) -> None:
        # its rule's level in its protocol's spec (``spec.RULES``: every protocol's); MUST when unknown
        self.level = self.level or (RULES[self.rule].level if self.rule in RULES else "MUST")

    @property
    def key(self) -> tuple[str, str]:
        return (self.rule, self.shape)

    def to_json(self) -> dict[str, Any]:
        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name not in _RUNTIME}
        d = json.loads(json.dumps(d))  # a copy, as finding.json will read
        d.update(self.doc)
        d["schema_version"] = FINDING_SCHEMA
        d["rule_text"] = RULES[self.rule].text if self.rule in RULES else ""
        return d

    @classmethod
    def from_flaw(cls, flaw: Flaw, datagrams: list[bytes], shape: str, engine: str, seed: int,
                  pace: str, **kw: Any) -> Finding:
        return cls(flaw.rule, flaw.expected, flaw.actual, [d.hex() for d in datagrams], shape,
                   engine, seed, pace, evidence=list(flaw.evidence), source=flaw.source, **kw)

    def describe(self) -> str:
        if self.shape == NO_INPUT:
            return (f"{self.rule} ({self.level}) [the node's behaviour whatever it is sent, no input blamed: "
                    f"a valid WP_Off in its place shows it, x{self.occurrences}]: {self.actual}")
        return (f"{self.rule} ({self.level}) [{self.engine}, {len(self.datagrams)} datagram(s), "
                f"x{self.occurrences}]: {self.actual}")


def finding_from_json(d: Any) -> Finding:
    """A finding from its recorded form (``finding.json``, or the ``finding`` value of a
    repro.mcap's metadata record): the one way back; ValueError says what is wrong."""
    if not isinstance(d, dict):
        raise ValueError("not a JSON object")
    try:
        d = {**{new: d[old] for new, old in _OLD_KEYS.items() if old in d}, **d}
        names = [f.name for f in fields(Finding) if f.name not in _RUNTIME]
        kw = {"expected": "", "actual": "", "shape": "", "datagrams": [], "engine": "stateful" if d.get("program") else "stateless",
              "seed": 0, **{k: d[k] for k in names if k in d}}
        own = {k: v for k, v in d.items() if k not in names and k not in ("schema_version", "rule_text")}
        f = Finding(**kw, doc=own)
        [bytes.fromhex(x) for x in f.datagrams]
    except (TypeError, ValueError, KeyError, AttributeError) as exc:
        raise ValueError(str(exc)) from None
    return f


def read_finding(path: str | Path, protocol: str | None = None) -> Finding:
    """A finding from ``finding-N/``, its ``finding.json``, its repro.mcap or (a stream
    protocol's) its repro.pcap (``fuzz.finding_files``), of ``protocol`` when given;
    ValueError (one line) says what is wrong."""
    d = read_finding_doc(path)
    try:
        f = finding_from_json(d)
    except ValueError as exc:
        raise ValueError(f"{str(path)!r} is not a finding: {exc}") from None
    if protocol is not None and f.protocol != protocol:
        raise ValueError(f"{str(path)!r} is not a finding of --protocol {protocol} (it is {f.protocol}'s)")
    return f


def load_finding(path: str | Path, protocol: str | None = None) -> Finding:
    """:func:`read_finding` for ``--replay``: its errors say so."""
    try:
        return read_finding(path, protocol)
    except ValueError as exc:
        raise ValueError(f"--replay: {exc}") from None


#: How a protocol writes a finding's captures into its ``finding-N/`` (the finding's
#: ``traffic``: its confirming replay's, empty when unknown).
Repro = Callable[[Path, "Finding"], None]


class FindingStore:
    """The campaign's findings, grouped by (rule, shape), whatever the protocol; thread-safe.
    ``replay_args``: ``mcp-fuzz``'s words after ``--replay DIR`` in replay.txt; ``repro``:
    the protocol's captures of a finding (default: MCP's repro.mcap, :func:`write_repro`)."""

    def __init__(self, out: str | Path | None, replay_args: list[str] | None = None,
                 repro: Repro | None = None) -> None:
        self.out = Path(out) if out is not None else None
        self.replay_args = replay_args or []
        self.repro: Repro = repro or (lambda d, f: write_repro(d / "repro.mcap", f, f.traffic or None))
        self._lock = threading.Lock()
        self.groups: dict[tuple[str, str], Finding] = {}
        self.order: list[Finding] = []
        self.unconfirmed: Counter[str] = Counter()

    def known(self, rule: str, shape: str) -> bool:
        with self._lock:
            return (rule, shape) in self.groups

    def count(self, rule: str, shape: str) -> None:
        """Another occurrence of a known group."""
        with self._lock:
            f = self.groups.get((rule, shape))
            if f is not None:
                f.occurrences += 1

    def add(self, finding: Finding, traffic: list[Any] | None = None) -> Path | None:
        """Keep a confirmed finding (or count it in its group); write it under --out, with
        ``traffic`` (its confirming replay's) when given, else its own."""
        if traffic is not None:
            finding.traffic = list(traffic)
        with self._lock:
            prev = self.groups.get(finding.key)
            if prev is not None:
                prev.occurrences += finding.occurrences
                return None
            self.groups[finding.key] = finding
            self.order.append(finding)
            n = len(self.order)
        if self.out is None:
            return None
        d = finding_dir(self.out, n)
        write_finding_doc(d, finding.to_json(), ["--replay", "{dir}", *self.replay_args])
        self.repro(d, finding)
        return d

    def rewrite(self) -> None:
        """Occurrence counts change after a finding is first written: write them again."""
        if self.out is None:
            return
        for n, f in enumerate(self.order, 1):
            p = self.out / f"finding-{n}" / "finding.json"
            if p.parent.is_dir():
                p.write_text(json.dumps(f.to_json(), indent=2) + "\n")

    def by_rule(self) -> dict[str, int]:
        with self._lock:
            c: Counter[str] = Counter()
            for f in self.order:
                c[f.rule] += f.occurrences
            return dict(sorted(c.items()))

    def __len__(self) -> int:
        with self._lock:
            return len(self.order)


def finding_from_metadata(meta: dict[str, str]) -> Finding | None:
    """The finding a repro.mcap's metadata record describes (its ``finding`` value, read as
    ``finding.json`` is), or None when it is not one (another recorder, or a capture written
    before the record held the finding)."""
    from mcp_conform.traceio.recorder import FUZZ_RECORDER

    if meta.get("recorder") != FUZZ_RECORDER:
        return None
    try:
        if "finding" in meta:
            return finding_from_json(json.loads(meta["finding"]))
        if "datagrams" not in meta or "rule" not in meta:
            return None
        # a repro.mcap written before the record held the whole finding
        return finding_from_json({
            "rule": meta["rule"], "expected": meta.get("expected", ""), "actual": meta.get("actual", ""),
            "datagrams": json.loads(meta["datagrams"]), "shape": meta.get("shape", ""),
            "engine": meta.get("engine", ""), "seed": int(meta.get("seed", "0")),
            "pace": meta.get("pace", "batch"), "scenario": meta.get("scenario"),
            "target": json.loads(meta["target"]) if "target" in meta else {}})
    except (ValueError, TypeError, RecursionError):
        return None


def write_repro(path: Path, f: Finding, traffic: list[tuple[str, int, bytes, tuple[str, int]]] | None,
                ) -> None:
    """The minimal sequence (and, when known, the node's answers) as an MCAP capture
    (``fuzz.finding_files.write_packets_repro``), with what ``mcp-capture replay`` needs to
    reproduce the finding as ``mcp-fuzz --replay`` does."""
    role = f.target.get("role") or pick(f.protocol)[1].name  # a finding written before it was recorded
    write_packets_repro(path, f, role, traffic, "tx", lambda rec, r: rec.datagram(
        r[0], r[2], r[3] if len(r) > 3 else ("127.0.0.1", 0), r[1]), expected=f.expected, actual=f.actual,
        engine=f.engine, seed=f.seed, pace=f.pace, scenario=f.scenario, target=f.target or None,
        datagrams=f.datagrams, shape=f.shape)


def write_summary(path: Path, summary: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(summary, indent=2) + "\n")
    tmp.replace(path)
