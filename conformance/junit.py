"""JUnit XML of a run (``--mcp-junit``): one testcase per case, rule IDs, level and outcome as
properties; ``xunit2`` (valid against the Jenkins junit-10 schema) or ``xunit1``.

One verdict in every report: a case the runner judges an ``error`` — it ran out of time
(the runner's per-case limit or pytest-timeout's shorter ``--timeout``), lost the node, or
raised something other than a rule's ``CaseFailure`` — is an error of the harness, not a
failure of the node: ``<error>`` here, ``error`` in the JSON report, and ``<error>`` in
pytest's own ``--junitxml`` too (``as_pytest_error``; pytest alone would write any exception
of a test's call as a ``<failure>``). A time limit is never the observation: a case that
judges silence waits a bounded window and fails the rule (``<failure type=RULE>``) itself.
"""

from __future__ import annotations

import socket
import time
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

from mcp_conform.conformance.report import (
    JUNIT_FAMILIES,
    CaseRecord,
    RunRecord,
    monitor_failures,
    spec_of,
)
from mcp_conform.spec import RULES
from mcp_conform.spec.about import TOOL_NAME

__all__ = ["as_pytest_error", "junit_xml", "write_junit"]


def _finding(c: CaseRecord) -> str:
    """What a case found, as text: the rule, expected, actual, evidence and notes."""
    lines = []
    if c.failed_rule:
        rule = RULES.get(c.failed_rule)
        lines.append(f"{c.failed_rule}: {rule.text if rule else ''}".rstrip())
        if c.expected is not None:
            lines.append(f"expected: {c.expected}")
        if c.actual is not None:
            lines.append(f"actual:   {c.actual}")
        lines += [f"evidence: {e}" for e in c.evidence]
        lines += [f"note: {n}" for n in c.notes if c.actual is None or n not in c.actual]
    else:
        if c.reason:
            lines.append(c.reason)
        lines += [f"evidence: {e}" for e in c.evidence]
        lines += [f"note: {n}" for n in c.notes]
    return "\n".join(lines)


def _iso(wall: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(wall))


def _case_properties(c: CaseRecord) -> list[tuple[str, str]]:
    props = [("rule", r) for r in c.rules]
    props += [("level", c.level), ("outcome", c.outcome)]
    if c.failed_rule:
        props.append(("failed_rule", c.failed_rule))
    if c.baseline:
        props.append(("baseline", c.baseline))
    return props


def _run_error_case(run: RunRecord) -> tuple[str, str]:
    """The name of the testcase that carries a run's error, and its type."""
    if run.error and run.error.startswith("interrupted"):
        return "run interrupted", "interrupted"
    if run.error and run.error.startswith("run deadline"):
        return "run deadline", "deadline"
    return ("setup" if not run.cases else "run"), "setup-error" if not run.cases else "run-error"


def junit_xml(run: RunRecord, family: str = "xunit2") -> str:
    """JUnit XML that CI systems show truthfully.

    failed -> ``<failure type=RULE message="RULE: what was seen">`` (the rule's text, expected
    and evidence in its body); error -> ``<error>``; skipped -> ``<skipped>`` with
    the reason; warned passes (a failure under --strict, where it is already ``failed``)
    but its name ends in `` [warned]`` and the finding is in ``<system-out>``; info passes
    with the finding in ``<system-out>``; xfailed (a baseline's expected failure) is
    ``<skipped type="xfailed">``, like pytest's xfail; xpassed passes with `` [xpassed]``,
    or fails under --strict. A setup error or an interrupted run is an ``<error>``
    testcase of its own, so no CI shows "no tests" or green for it.
    """
    if family not in JUNIT_FAMILIES:
        raise ValueError(f"unknown JUnit family {family!r}")
    counts = run.counts()
    # rules the run's monitor proved violated and no case failed (its consequences of a case's
    # root failure stay in the JSON and the terminal: the run fails already)
    monitor = [f for f in monitor_failures(run) if not f["consequence_of"]]
    counted = [f for f in monitor if f["outcome"] == "failed" or run.strict]
    failures = counts["failed"] + (counts["xpassed"] if run.strict else 0) + len(counted)
    errors = counts["error"] + (1 if run.error is not None else 0)
    suite = ET.Element("testsuite", {
        "name": TOOL_NAME,
        "tests": str(len(run.cases) + len(monitor) + (1 if run.error is not None else 0)),
        "failures": str(failures), "errors": str(errors),
        "skipped": str(counts["skipped"] + counts["xfailed"]),
        "time": f"{run.duration_s:.3f}", "timestamp": _iso(run.started_wall),
        "hostname": socket.gethostname(),
    })
    props = ET.SubElement(suite, "properties")

    def prop(parent: ET.Element, key: str, value: Any) -> None:
        ET.SubElement(parent, "property", {"name": key, "value": "" if value is None else str(value)})

    for key, value in (("target", run.target), ("role", run.role), ("seed", run.seed),
                       ("spec_version", spec_of(run.role).version), ("strict", run.strict)):
        prop(props, key, value)
    if run.error is not None:
        prop(props, "error", run.error)
    if family == "xunit2":  # junit-10 has no testcase properties: name them after the case
        for c in run.cases:
            for key, value in _case_properties(c):
                prop(props, f"{c.id}.{key}", value)
    if run.error is not None:
        name, kind = _run_error_case(run)
        tc = ET.SubElement(suite, "testcase", {"classname": f"{TOOL_NAME}.run", "name": name, "time": "0.000"})
        ET.SubElement(tc, "error", {"message": run.error, "type": kind}).text = run.error
    for c in run.cases:
        name = c.id + (f" [{c.outcome}]" if c.outcome in ("warned", "xpassed") else "")
        tc = ET.SubElement(suite, "testcase", {"classname": f"{TOOL_NAME}.{c.group}", "name": name,
                                               "time": f"{c.duration_s:.3f}"})
        if family == "xunit1":
            tprops = ET.SubElement(tc, "properties")
            for key, value in _case_properties(c):
                prop(tprops, key, value)
        finding = _finding(c)
        message = (c.reason or "").splitlines()[0] if c.reason else c.outcome
        if c.failed_rule and c.actual:  # what was seen (the rule's text is in the body)
            message = f"{c.failed_rule}: {c.actual.splitlines()[0]}"
        if c.outcome == "failed" or (c.outcome == "xpassed" and run.strict):
            if c.outcome == "xpassed":
                message = f"expected to fail ({c.baseline}) but passed: take it off the baseline"
            ET.SubElement(tc, "failure", {"message": message, "type": c.failed_rule or c.outcome}).text = finding
        elif c.outcome == "error":
            ET.SubElement(tc, "error", {"message": message, "type": "error"}).text = finding
        elif c.outcome == "skipped":
            ET.SubElement(tc, "skipped", {"message": c.reason or "skipped"})
        elif c.outcome == "xfailed":
            ET.SubElement(tc, "skipped", {"message": f"xfailed: {c.baseline}", "type": "xfailed"}).text = finding
        elif finding or c.outcome == "xpassed":
            extra = f" (baseline: {c.baseline})" if c.outcome == "xpassed" else ""
            ET.SubElement(tc, "system-out").text = f"{c.outcome.upper()}{extra}: {finding}"
    for f in monitor:  # one testcase per rule: the monitor's violations of it, counted
        n = f["violations"]
        tc = ET.SubElement(suite, "testcase", {"classname": f"{TOOL_NAME}.monitor",
                                               "name": f"monitor/{f['rule']}"
                                               + (" [warned]" if f["outcome"] == "warned" else ""),
                                               "time": "0.000"})
        text = (f"{f['rule']}: {n} violation(s) proved by the run's trace monitor; "
                f"first: {f['actual']}")
        if f in counted:
            ET.SubElement(tc, "failure", {"message": f["actual"], "type": f["rule"]}).text = text
        else:
            ET.SubElement(tc, "system-out").text = f"WARNED: {text}"
    root = ET.Element("testsuites", {"name": TOOL_NAME, "tests": suite.get("tests", "0"),
                                     "failures": str(failures), "errors": str(errors),
                                     "time": f"{run.duration_s:.3f}"})
    root.append(suite)
    ET.indent(root)
    return '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def write_junit(path: str | Path, run: RunRecord, family: str = "xunit2") -> None:
    try:
        Path(path).write_text(junit_xml(run, family), encoding="utf-8")
    except OSError as exc:
        raise OSError(f"--junit: cannot write {str(path)!r}: {exc.strerror}") from None


def as_pytest_error(config: Any, report: Any) -> None:
    """pytest's ``--junitxml`` has just written the call of a case the runner judged an
    error (``report.mcp_outcome``) as a ``<failure>``: make it the ``<error>`` it is, with
    the suite's counts, so pytest's JUnit and ``--mcp-junit`` give the same verdict."""
    try:
        from _pytest.junitxml import xml_key
    except ImportError:  # pragma: no cover - a pytest without it
        return
    xml = config.stash.get(xml_key, None) if config is not None else None
    if xml is None:
        return
    reporter = xml.node_reporter(report)
    for node in reversed(reporter.nodes):
        if node.tag == "failure":
            node.tag = "error"
            if xml.stats.get("failure", 0) > 0:
                xml.stats["failure"] -= 1
                xml.stats["error"] = xml.stats.get("error", 0) + 1
            return

