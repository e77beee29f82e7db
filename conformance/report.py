"""The runner's reports: the live terminal report (rich), the JSON report and JUnit XML.

Everything here works on :class:`CaseRecord` and :class:`RunRecord`, filled in by the
plugin as cases finish; nothing here knows about pytest. The JSON report follows
docs/design.md ("The runner's contract") and is validated against ``report.schema.json``,
shipped beside this module (draft 2020-12, ``schema_version`` "1.1": 1.0 plus each case's
``failed_rule``, ``evidence``, ``notes`` and ``baseline``, and the ``xfailed`` / ``xpassed``
outcomes of an expected-failures baseline, ``conformance.baseline``).

Per-rule outcomes: a ``CaseFailure`` contributes its outcome to the rule it names only; a
pass contributes ``passed`` (``info`` for an INFO rule) to every rule of the case; a skip
(and an error: the rule was not judged) contributes ``skipped``. They aggregate worst-first
(failed > warned > xfailed > passed = xpassed > info > skipped); a rule no case touched is
``skipped``.

JUnit (``junit_xml``) comes in two families, as pytest's: ``xunit2`` (default) is valid
against the Jenkins xunit plugin's JUnit schema (junit-10), which allows no ``<properties>``
inside a ``<testcase>``: each case's rule IDs, level and outcome are then testsuite
properties named after the case; ``xunit1`` also puts them in each testcase, as pytest's
``record_property`` does (Jenkins' JUnit plugin, GitLab and junitparser read both).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from mcp_conform.spec import RULES, SpecBase
from mcp_conform.spec.about import TOOL_NAME, tool_version
from mcp_conform.spec.profiles import DEFAULT_PROTOCOL, PROFILES, ProfileError, profile_of_role

__all__ = [
    "OUTCOMES",
    "SCHEMA_VERSION",
    "CaseRecord",
    "RunRecord",
    "build_json",
    "failures_json",
    "case_from_json",
    "load_schema",
    "name_consequence",
    "roots_first",
    "monitor_failures",
    "rule_outcomes",
    "run_from_json",
    "spec_of",
    "tool_version",
    "validate_json",
    "write_json",
]

SCHEMA_VERSION = "1.5"  # 1.2: the monitor's violations in failures and rules; 1.3: spec.protocol, role backend (Nsqd); 1.4: monitor.vetoed; 1.5: rule outcome consequence
OUTCOMES: tuple[str, ...] = ("passed", "failed", "warned", "skipped", "info", "error", "xfailed", "xpassed")
#: a rule's outcome in the rules table: a case's (OUTCOMES but error), or ``consequence``: the
#: trace monitor proved it violated after another rule failed, as that failure's consequence
#: (``failures`` names the root; neither passed nor a failure of its own)
CONSEQUENCE = "consequence"
RULE_RANK = {"failed": 6, "warned": 5, "xfailed": 4, CONSEQUENCE: 3, "passed": 2, "xpassed": 2, "info": 1, "skipped": 0}
STYLES = {"passed": "green", "failed": "bold red", "warned": "yellow", "skipped": "blue",
          "info": "cyan", "error": "bold magenta", "xfailed": "dim yellow", "xpassed": "bold yellow",
          CONSEQUENCE: "dim red"}
JUNIT_FAMILIES = ("xunit2", "xunit1")


@dataclass
class CaseRecord:
    """One case as the reports show it."""

    id: str
    rules: tuple[str, ...]
    level: str
    outcome: str = "passed"
    reason: str | None = None
    expected: str | None = None
    actual: str | None = None
    duration_s: float = 0.0
    start_ns: int | None = None
    end_ns: int | None = None
    failed_rule: str | None = None  # the rule a CaseFailure named
    evidence: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    baseline: str | None = None  # the baseline entry's reason, for xfailed / xpassed
    relies_on: tuple[str, ...] = ()  # rules the failing observation relied on (CaseFailure)
    consequence_of: list[str] = field(default_factory=list)  # of those, the ones that failed first

    @property
    def is_root_failure(self) -> bool:
        return self.outcome in ("failed", "warned") and not self.consequence_of

    @property
    def group(self) -> str:
        return self.id.split("/", 1)[0] if "/" in self.id else "CASE"

    def to_json(self) -> dict[str, Any]:
        return {
            "id": self.id, "rules": list(self.rules), "level": self.level, "outcome": self.outcome,
            "reason": self.reason, "expected": self.expected, "actual": self.actual,
            "duration_s": round(max(self.duration_s, 0.0), 6),
            "capture": {"start_ns": self.start_ns, "end_ns": self.end_ns},
            "failed_rule": self.failed_rule, "evidence": list(self.evidence),
            "notes": list(self.notes), "baseline": self.baseline,
            "consequence_of": list(self.consequence_of),
        }


def name_consequence(rec: CaseRecord, earlier: list[CaseRecord]) -> None:
    """A failure whose observation relied on a rule that already failed (spec ``depends_on``)
    is still reported, as that rule's consequence: ``consequence_of`` lists it and the reason
    says so ("consequence of MCP-ACK-1 (failed)"). Outcomes and exit codes do not change."""
    if rec.outcome not in ("failed", "warned") or not rec.relies_on:
        return
    failed = {c.failed_rule: c.outcome for c in earlier
              if c.outcome in ("failed", "warned") and c.failed_rule}
    rec.consequence_of = [r for r in rec.relies_on if r in failed and r != rec.failed_rule]
    if rec.consequence_of:
        why = ", ".join(f"{r} ({failed[r]})" for r in rec.consequence_of)
        rec.reason = f"consequence of {why}: {rec.reason}" if rec.reason else f"consequence of {why}"


def roots_first(cases: list[Any]) -> list[Any]:
    """The failed and warned cases (records or JSON dicts): root failures first, then those
    that are consequences of earlier failures, each in run order."""
    def get(c: Any, key: str) -> Any:
        return c.get(key) if isinstance(c, dict) else getattr(c, key)
    bad = [c for c in cases if get(c, "outcome") in ("failed", "warned")]
    return sorted(bad, key=lambda c: bool(get(c, "consequence_of")))


def failures_json(cases: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The JSON ``failures`` list: every failed or warned case, root failures first."""
    return [{"case": c["id"], "rule": c.get("failed_rule"), "outcome": c["outcome"],
             "consequence_of": list(c.get("consequence_of") or [])} for c in roots_first(cases)]


@dataclass
class RunRecord:
    """The whole run: parameters, cases so far, and the error that stopped it, if any."""

    role: str = PROFILES[DEFAULT_PROTOCOL].default_role.name
    target: str | None = None
    parameters: dict[str, Any] = field(default_factory=dict)
    seed: int | None = None
    strict: bool = False
    error: str | None = None
    node: dict[str, Any] | None = None  # a spawn failure: the node's command, exit, stdout, stderr
    error_detail: list[str] = field(default_factory=list)  # what explains the setup error
    cases: list[CaseRecord] = field(default_factory=list)
    started: float = field(default_factory=time.monotonic)
    started_wall: float = field(default_factory=time.time)
    finished: float | None = None
    monitor: dict[str, Any] | None = None  # the trace monitor's section (judge.run_monitor)
    schedule: dict[str, Any] | None = None  # the run's plan (conformance.schedule)

    @property
    def duration_s(self) -> float:
        end = self.finished if self.finished is not None else time.monotonic()
        return max(0.0, end - self.started)

    def counts(self) -> dict[str, int]:
        out = dict.fromkeys(OUTCOMES, 0)
        for c in self.cases:
            out[c.outcome] = out.get(c.outcome, 0) + 1
        return out

    def exit_code(self) -> int:
        """The contract: 2 usage/setup error, 1 a case failed or errored, a MUST the run's
        trace monitor proved violated (a SHOULD too under --strict), or, under --strict, a
        baseline's expected failure now passes; else 0."""
        if self.error is not None:
            return 2
        counts = self.counts()
        monitor = [f for f in monitor_failures(self) if not f["consequence_of"]]
        return 1 if (counts["failed"] or counts["error"] or (self.strict and counts["xpassed"])
                     or any(f["outcome"] == "failed" for f in monitor)
                     or (self.strict and any(f["outcome"] == "warned" for f in monitor))) else 0


def monitor_failures(run: RunRecord) -> list[dict[str, Any]]:
    """The rules the run's trace monitor proved violated by the node under test and no case
    failed or warned (one fault, one entry: a case's failure of the same rule stands for it),
    with the count and the first violation; outcome failed for a MUST, warned for a SHOULD."""
    mon = run.monitor or {}
    by_case = {c.failed_rule for c in run.cases if c.outcome in ("failed", "warned", "xfailed")}
    # one fault, one root: what the monitor proves after a case failed or warned (a node that
    # broke one rule may fail the next ones because of it) is listed as that case's
    # consequence, not as a rule failed of its own; what it proves before any is a root
    failing = [(c.start_ns, c.failed_rule) for c in run.cases
               if c.outcome in ("failed", "warned") and c.failed_rule and c.start_ns is not None]
    seen: dict[str, dict[str, Any]] = {}
    for v in mon.get("violations", []):
        rule = v.get("rule")
        if rule in by_case or rule not in RULES:
            continue
        level = RULES[rule].level
        if level not in ("MUST", "SHOULD"):
            continue
        entry = seen.get(rule)
        if entry is None:
            t = v.get("t_ns")
            roots = sorted({r for start, r in failing if t is None or start <= t})
            seen[rule] = {"case": "monitor", "rule": rule, "outcome": "failed" if level == "MUST" else "warned",
                          "consequence_of": roots, "source": "monitor", "violations": 1,
                          "actual": f"node {v.get('node')}: {v.get('actual')}"}
        else:
            entry["violations"] += 1
    return [seen[r] for r in sorted(seen)]


# ---------------------------------------------------------------------- JSON
def spec_of(role: str) -> SpecBase:
    """The spec of the protocol whose nodes take ``role`` (``spec.profiles``); an unknown
    role (a foreign report's): the default protocol's."""
    try:
        return profile_of_role(role).spec
    except ProfileError:
        return PROFILES[DEFAULT_PROTOCOL].spec


def _spec_json(role: str) -> dict[str, Any]:
    sp = spec_of(role)
    return {"protocol": sp.protocol["short_name"], "version": sp.version, "sha256": sp.sha256}


def _rule_ids_for(role: str) -> list[str]:
    try:
        return [r.id for r in spec_of(role).rules_for(role)]
    except Exception:  # noqa: BLE001 - an unknown role: no rules to list
        return []


def monitor_outcome(f: dict[str, Any]) -> str:
    """A ``monitor_failures`` entry's contribution to its rule's row: its outcome, or
    ``consequence`` when it is an earlier failure's (one fault, one root; the row never says
    passed beside a failure the report lists)."""
    return CONSEQUENCE if f.get("consequence_of") else f["outcome"]


def consequences_of(failures: list[dict[str, Any]]) -> dict[str, list[str]]:
    """Rule -> the roots named by the monitor's consequence entries of ``failures`` (what a
    ``consequence`` row refers to)."""
    out: dict[str, list[str]] = {}
    for f in failures:
        if f.get("source") == "monitor" and f.get("consequence_of") and f.get("rule"):
            roots = out.setdefault(f["rule"], [])
            roots += [r for r in f["consequence_of"] if r not in roots]
    return out


def rule_outcomes(cases: list[CaseRecord], role: str,
                  monitor: list[dict[str, Any]] | None = None) -> dict[str, str]:
    """Every rule of the role (plus any rule a case named) -> its aggregate outcome, the
    rules the run's trace monitor proved violated (``monitor_failures``) included: a
    violation it proved as an earlier failure's consequence makes the row ``consequence``
    (above passed, below any failure of the rule's own)."""
    result: dict[str, str] = dict.fromkeys(_rule_ids_for(role), "skipped")

    def contribute(rule: str, outcome: str) -> None:
        old = result.get(rule, "skipped")
        if RULE_RANK[outcome] >= RULE_RANK[old]:
            result[rule] = outcome

    for c in cases:
        if c.outcome in ("failed", "warned", "xfailed") or (c.outcome == "info" and c.failed_rule):
            contribute(c.failed_rule or (c.rules[0] if c.rules else "?"), c.outcome)
        elif c.outcome == "xpassed":
            for r in c.rules:
                contribute(r, "xpassed")
        elif c.outcome in ("passed", "info"):
            for r in c.rules:
                rule = RULES.get(r)
                contribute(r, "info" if rule is not None and rule.level == "INFO" else "passed")
        else:  # skipped, error: not judged
            for r in c.rules:
                contribute(r, "skipped")
    for f in monitor or ():  # a consequence is its root's, not a rule failed anew: nor passed
        contribute(f["rule"], monitor_outcome(f))
    return result


def build_json(run: RunRecord) -> dict[str, Any]:
    """The report document (see docs/design.md and report.schema.json)."""
    counts = run.counts()
    monitor = monitor_failures(run)
    doc: dict[str, Any] = {
        "schema_version": SCHEMA_VERSION,
        "tool": {"name": TOOL_NAME, "version": tool_version()},
        "spec": _spec_json(run.role),
        "target": run.target,
        "role": run.role,
        "parameters": dict(run.parameters),
        "seed": run.seed,
        "error": run.error,
        "cases": [c.to_json() for c in run.cases],
        "failures": failures_json([c.to_json() for c in run.cases]) + monitor,
        "rules": rule_outcomes(run.cases, run.role, monitor),
        "summary": {**{k: counts[k] for k in OUTCOMES}, "duration_s": round(run.duration_s, 3)},
        **({"monitor": run.monitor} if run.monitor is not None else {}),
        **({"schedule": run.schedule} if run.schedule is not None else {}),
    }
    if run.node is not None:
        doc["node"] = run.node
    if run.error_detail:
        doc["error_detail"] = list(run.error_detail)
    return doc


_MONITOR_RANK = {"not_observed": 0, "info": 1, "passed": 2, "warned": 3, "failed": 4}


def merge_monitor(sections: list[dict[str, Any]]) -> dict[str, Any]:
    """The ``monitor`` sections of several workers' runs (each against its own node) as one:
    datagrams summed, violations concatenated, each node's verdicts worst-first. A frame
    monitor's sections (MAVLink's: frames, nodes by SYSID/COMPID, one rule table) merge as
    :func:`_merge_frame_monitor` says."""
    if any("frames" in m for m in sections):
        return _merge_frame_monitor(sections)
    out = {"complete": all(m.get("complete", True) for m in sections),
           "datagrams": sum(m.get("datagrams", 0) for m in sections),
           "nodes": [], "violations": [v for m in sections for v in m.get("violations", [])], "rules": {}}
    seen: dict[int, dict[str, Any]] = {}
    for m in sections:
        for n in m.get("nodes", []):
            if n["id"] in seen:
                seen[n["id"]]["datagrams"] += n["datagrams"]
                seen[n["id"]]["addresses"] = sorted({*seen[n["id"]]["addresses"], *n["addresses"]})
            else:
                seen[n["id"]] = dict(n)
        for node, table in m.get("rules", {}).items():
            merged = out["rules"].setdefault(node, {})
            for rule, verdict in table.items():
                if _MONITOR_RANK[verdict] >= _MONITOR_RANK.get(merged.get(rule, "not_observed"), 0):
                    merged[rule] = verdict
    out["nodes"] = [seen[k] for k in sorted(seen)]
    return out


def _merge_frame_monitor(sections: list[dict[str, Any]]) -> dict[str, Any]:
    """A frame monitor's sections as one: frames summed, each node's (SYSID/COMPID) frame and
    heartbeat counts summed, violations concatenated, each rule's verdict worst-first, the
    failure counts summed."""
    out: dict[str, Any] = {"complete": all(m.get("complete", True) for m in sections),
                           "frames": sum(m.get("frames", 0) for m in sections), "nodes": [],
                           "violations": [v for m in sections for v in m.get("violations", [])],
                           "failed_count": {}, "rules": {}}
    seen: dict[str, dict[str, Any]] = {}
    for m in sections:
        for n in m.get("nodes", []):
            if n["id"] in seen:
                for k in ("frames", "heartbeats"):
                    seen[n["id"]][k] = seen[n["id"]].get(k, 0) + n.get(k, 0)
            else:
                seen[n["id"]] = dict(n)
        for rule, count in m.get("failed_count", {}).items():
            out["failed_count"][rule] = out["failed_count"].get(rule, 0) + count
        for rule, verdict in m.get("rules", {}).items():
            if _MONITOR_RANK[verdict] >= _MONITOR_RANK.get(out["rules"].get(rule, "not_observed"), 0):
                out["rules"][rule] = verdict
    out["nodes"] = [seen[k] for k in sorted(seen)]
    return out


def load_schema() -> dict[str, Any]:
    """The shipped JSON Schema of the report."""
    text = resources.files("mcp_conform.conformance").joinpath("report.schema.json").read_text("utf-8")
    return dict(json.loads(text))


def validate_json(doc: dict[str, Any]) -> None:
    """Raise ``jsonschema.ValidationError`` if ``doc`` does not follow the schema."""
    import jsonschema

    jsonschema.Draft202012Validator(load_schema()).validate(doc)


def write_json(path: str | Path, run: RunRecord) -> None:
    """Write the JSON report (an OSError names the file)."""
    doc = build_json(run)
    try:  # whole or not at all: written beside, then renamed over the old file
        tmp = Path(f"{path}.tmp")
        tmp.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
        tmp.replace(path)
    except OSError as exc:
        raise OSError(f"--json: cannot write {str(path)!r}: {exc.strerror}") from None


def merge_json(docs: list[dict[str, Any]]) -> dict[str, Any]:
    """One report from the reports of several pytest-xdist workers (each ran some cases
    against its own spawned node): cases concatenated, rule outcomes worst-first, counts
    summed, the longest duration, the first error."""
    if not docs:
        raise ValueError("no worker reports to merge")
    out = dict(docs[0])
    out["cases"] = [c for d in docs for c in d.get("cases", [])]
    out["failures"] = failures_json(out["cases"])
    rules: dict[str, str] = {}
    for d in docs:
        for rule, outcome in d.get("rules", {}).items():
            if rule not in rules or RULE_RANK[outcome] > RULE_RANK[rules[rule]]:
                rules[rule] = outcome
    out["rules"] = rules
    out["error"] = next((d["error"] for d in docs if d.get("error")), None)
    summary = dict.fromkeys(OUTCOMES, 0)
    for c in out["cases"]:
        summary[c["outcome"]] += 1
    out["summary"] = {**summary, "duration_s": max(d["summary"]["duration_s"] for d in docs)}
    out["target"] = ", ".join(sorted({str(d.get("target")) for d in docs}))
    sections = [d["monitor"] for d in docs if d.get("monitor")]
    out.pop("monitor", None)
    if sections:
        out["monitor"] = merge_monitor(sections)
    monitor = monitor_failures(run_from_json(out))  # over the merged cases, as one run's
    out["failures"] += monitor
    for f in monitor:
        if RULE_RANK[monitor_outcome(f)] > RULE_RANK[rules.get(f["rule"], "skipped")]:
            rules[f["rule"]] = monitor_outcome(f)
    return out


def worker_path(path: str, worker: str) -> str:
    """Where an xdist worker records its part of FILE: ``run.mcap`` -> ``run.gw0.mcap``
    (the extension kept, so every tool still opens the part)."""
    p = Path(path)
    return str(p.with_name(f"{p.stem}.{worker}{p.suffix}")) if p.suffix else f"{path}.{worker}"


def case_from_json(d: dict[str, Any]) -> CaseRecord:
    """A ``CaseRecord`` from its JSON form (a worker's report, a report file)."""
    cap = d.get("capture") or {}
    return CaseRecord(
        id=d["id"], rules=tuple(d.get("rules", ())), level=d.get("level", "MUST"),
        outcome=d.get("outcome", "error"), reason=d.get("reason"), expected=d.get("expected"),
        actual=d.get("actual"), duration_s=float(d.get("duration_s") or 0.0),
        start_ns=cap.get("start_ns"), end_ns=cap.get("end_ns"), failed_rule=d.get("failed_rule"),
        evidence=list(d.get("evidence") or []), notes=list(d.get("notes") or []),
        baseline=d.get("baseline"), consequence_of=list(d.get("consequence_of") or []),
    )


def run_from_json(doc: dict[str, Any]) -> RunRecord:
    """A ``RunRecord`` from a report document (e.g. the merge of xdist workers' reports),
    so the JUnit and the terminal summary are made from it as from a live run."""
    params = dict(doc.get("parameters") or {})
    run = RunRecord(role=doc.get("role", RunRecord.role), target=doc.get("target"), parameters=params,
                    seed=doc.get("seed"), strict=bool(params.get("strict", False)), error=doc.get("error"))
    run.cases = [case_from_json(c) for c in doc.get("cases", [])]
    run.finished = run.started + float((doc.get("summary") or {}).get("duration_s") or 0.0)
    run.monitor = doc.get("monitor")
    run.error_detail = list(doc.get("error_detail") or [])
    return run
