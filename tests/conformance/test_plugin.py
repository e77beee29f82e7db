"""conformance.plugin through pytester, against a FAKE session (no network, no node).

The fake comes in through the plugin's ``pytest_mcp_make_session`` hook, implemented in a
conftest; tiny cases pass, fail a MUST, fail a SHOULD, are inconclusive, record INFO.
"""

from __future__ import annotations

import json
import os
import textwrap
import xml.etree.ElementTree as ET

import pytest

from mcp_conform.conformance.report import validate_json

pytest_plugins = ("pytester",)



def _plugin_is_installed() -> bool:
    """True when pytest loads the plugin through its ``pytest11`` entry point (the pytester
    sessions here are plain pytest runs, autoload on, as a user's ``pytest --pyargs`` is)."""
    if os.environ.get("PYTEST_DISABLE_PLUGIN_AUTOLOAD"):
        return False
    from importlib.metadata import entry_points

    return any(ep.value.strip() == "mcp_conform.conformance.plugin" for ep in entry_points(group="pytest11"))


PLUGIN = [] if _plugin_is_installed() else ["-p", "mcp_conform.conformance.plugin"]

CONFTEST = """
import json, time
from mcp_conform.conformance._case_base import CaseBase
from mcp_conform.harness.errors import SetupError, TargetLost
from mcp_conform.harness.node import NodeBase

SETUP_ERROR = {setup_error!r}
LOST_AFTER = {lost_after!r}
CASE_TIMEOUT = {case_timeout!r}

class FakeCtx(CaseBase):
    def __init__(self, case_id, rules):
        super().__init__(None, case_id, rules)

class FakeSession(NodeBase):
    def __init__(self, cfg, recorder=None):
        self.cfg, self.recorder, self.target_desc, self.target_id = cfg, recorder, "127.0.0.1:9", 1
        self.begun = 0
        if CASE_TIMEOUT is not None:
            cfg.case_timeout = CASE_TIMEOUT
    def log(self, **kw):
        with open("session.log", "a") as f:
            f.write(json.dumps(kw) + "\\n")
    def start(self):
        self.log(event="start", rto=self.cfg.rto, embedded=self.cfg.embedded, strict=self.cfg.strict)
        if SETUP_ERROR:
            raise SetupError(SETUP_ERROR)
    def begin_case(self, case_id, rules):
        self.begun += 1
        if LOST_AFTER is not None and self.begun > LOST_AFTER:
            raise TargetLost("the node went silent")
        self.log(event="begin", case=case_id, rules=list(rules))
        return FakeCtx(case_id, rules)
    def end_case(self, ctx, outcome):
        ctx.end_ns = time.time_ns()
        self.log(event="end", case=ctx.case_id, outcome=outcome)
    def close(self):
        self.log(event="close")

def pytest_mcp_make_session(cfg, recorder, config):
    return FakeSession(cfg, recorder)
"""

CASES = """
import time
from mcp_conform.conformance.marks import rules
from mcp_conform.harness.errors import CaseFailure, Inconclusive

@rules("MCP-BLK-7", phase="end")
def test_end(node):
    pass

@rules("MCP-ACK-1")
def test_pass(node):
    pass

@rules("MCP-ACK-4")
def test_must_fails(node):
    raise CaseFailure("MCP-ACK-4", "no ACK for a broadcast", "an ACK naming seq 3", ["ACK seq 3 at 0.01 s"])

@rules("MCP-ACK-7")
def test_should_fails(node):
    raise CaseFailure("MCP-ACK-7", "median latency <= 0.1 s", "median 0.3 s")

@rules("MCP-BLK-2")
def test_inconclusive(node):
    raise Inconclusive("MCP-BLK-2 binds the manager")

@rules("MCP-HDR-1", phase="late")
def test_late(node):
    pass

@rules("MCP-SEQ-4", phase="startup")
def test_info(node):
    node.info("initial sequence number 1234")

@rules("MCP-ROB-1")
def test_crash(node):
    raise RuntimeError("boom in the case")

def test_plain_unmarked():
    pass
"""

ALL_IDS = ["SEQ/test_info", "ACK/test_pass", "ACK/test_must_fails", "ACK/test_should_fails",
           "BLK/test_inconclusive", "ROB/test_crash", "HDR/test_late", "BLK/test_end"]


def setup_files(pytester: pytest.Pytester, cases: str = CASES, *, setup_error: str | None = None,
                lost_after: int | None = None, case_timeout: float | None = None) -> None:
    pytester.makeconftest(CONFTEST.format(setup_error=setup_error, lost_after=lost_after,
                                          case_timeout=case_timeout))
    pytester.makepyfile(test_fake=textwrap.dedent(cases))


def run(pytester: pytest.Pytester, *args: str) -> tuple[pytest.RunResult, dict]:
    result = pytester.runpytest(*PLUGIN, "-p", "no:cacheprovider", "--mcp-json", "report.json", *args)
    path = pytester.path / "report.json"
    doc = json.loads(path.read_text()) if path.exists() else {}
    if doc:
        validate_json(doc)
    return result, doc


def log(pytester: pytest.Pytester) -> list[dict]:
    path = pytester.path / "session.log"
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


def outcomes(doc: dict) -> dict[str, str]:
    return {c["id"]: c["outcome"] for c in doc["cases"]}


def test_outcome_mapping_and_rules(pytester):
    setup_files(pytester)
    result, doc = run(pytester)
    assert result.ret == 1
    assert outcomes(doc) == {
        "SEQ/test_info": "info", "ACK/test_pass": "passed", "ACK/test_must_fails": "failed",
        "ACK/test_should_fails": "warned", "BLK/test_inconclusive": "skipped",
        "ROB/test_crash": "error", "HDR/test_late": "passed", "BLK/test_end": "passed"}
    by_id = {c["id"]: c for c in doc["cases"]}
    must = by_id["ACK/test_must_fails"]
    assert (must["level"], must["expected"], must["actual"]) == ("MUST", "no ACK for a broadcast", "an ACK naming seq 3")
    assert by_id["ACK/test_should_fails"]["level"] == "SHOULD"
    assert by_id["BLK/test_inconclusive"]["reason"] == "MCP-BLK-2 binds the manager"
    assert by_id["ROB/test_crash"]["reason"] == "RuntimeError: boom in the case"
    assert by_id["SEQ/test_info"]["actual"] == "initial sequence number 1234"
    cap = by_id["ACK/test_pass"]["capture"]
    assert isinstance(cap["start_ns"], int) and cap["end_ns"] >= cap["start_ns"]
    rules = doc["rules"]
    assert (rules["MCP-ACK-1"], rules["MCP-ACK-4"], rules["MCP-ACK-7"], rules["MCP-BLK-2"],
            rules["MCP-SEQ-4"], rules["MCP-DUP-1"]) == ("passed", "failed", "warned", "skipped", "info", "skipped")
    assert doc["summary"]["failed"] == 1 and doc["summary"]["warned"] == 1 and doc["summary"]["error"] == 1
    assert doc["error"] is None and doc["target"] == "127.0.0.1:9"
    # pytest's view: the warned SHOULD and the INFO pass, the MUST fails, the plain test runs
    result.assert_outcomes(passed=6, failed=1, errors=1, skipped=1)  # the crash: an error, as in our reports
    ends = {e["case"]: e["outcome"] for e in log(pytester) if e["event"] == "end"}
    assert ends == {k: v for k, v in outcomes(doc).items()}
    assert log(pytester)[-1]["event"] == "close"


def test_order_by_phase_keeps_file_order_otherwise(pytester):
    setup_files(pytester)
    _, doc = run(pytester)
    assert [c["id"] for c in doc["cases"]] == ALL_IDS
    begins = [e["case"] for e in log(pytester) if e["event"] == "begin"]
    assert begins == ALL_IDS


def test_terminal_output(pytester):
    setup_files(pytester)
    result, _ = run(pytester)
    out = result.stdout.str()
    assert "FAILED   ACK/test_must_fails  MCP-ACK-4" in out
    assert "expected: no ACK for a broadcast" in out and "actual:   an ACK naming seq 3" in out
    assert "WARNED   ACK/test_should_fails" in out
    assert "per-rule outcome" in out and "suite finished in" in out


def test_strict_makes_a_should_fail(pytester):
    setup_files(pytester)
    result, doc = run(pytester, "--mcp-strict", "--mcp-select", "MCP-ACK-7")
    assert result.ret == 1
    assert outcomes(doc) == {"ACK/test_should_fails": "failed"}
    assert doc["rules"]["MCP-ACK-7"] == "failed"


def test_warning_alone_exits_0(pytester):
    setup_files(pytester)
    result, doc = run(pytester, "--mcp-select", "MCP-ACK-7", "--mcp-select", "SEQ")
    assert result.ret == 0
    assert outcomes(doc) == {"SEQ/test_info": "info", "ACK/test_should_fails": "warned"}


def test_select_by_prefix(pytester):
    setup_files(pytester)
    _, doc = run(pytester, "--mcp-select", "ack/test_p", "--mcp-select", "MCP-BLK")
    assert [c["id"] for c in doc["cases"]] == ["ACK/test_pass", "BLK/test_inconclusive", "BLK/test_end"]


def test_select_rule_id_is_not_a_prefix_of_a_longer_number(pytester):
    setup_files(pytester, CASES + '\n@rules("MCP-ACK-1", "MCP-HDR-2")\ndef test_two(node):\n    pass\n')
    _, doc = run(pytester, "--mcp-select", "MCP-HDR-1")
    assert [c["id"] for c in doc["cases"]] == ["HDR/test_late"]


def test_select_matching_nothing_is_a_usage_error(pytester):
    setup_files(pytester)
    result, doc = run(pytester, "--mcp-select", "MCP-NOPE")
    assert result.ret == 2
    assert doc["error"] == "--mcp-select: no case matches MCP-NOPE" and doc["cases"] == []
    assert log(pytester) == []


def test_list_runs_nothing(pytester):
    setup_files(pytester)
    result, _ = run(pytester, "--mcp-list")
    assert result.ret == 0
    out = result.stdout.str()
    assert "ACK/test_must_fails  MCP-ACK-4  MUST" in out and "ACK/test_should_fails  MCP-ACK-7  SHOULD" in out
    assert "SEQ/test_info  MCP-SEQ-4  INFO  (startup)" in out and "8 cases" in out
    assert out.index("SEQ/test_info") < out.index("ACK/test_pass") < out.index("BLK/test_end")
    assert log(pytester) == []  # the session was never made


def test_setup_error_exits_2_with_the_reason(pytester):
    setup_files(pytester, setup_error="target never answered: no Mission_Ready within 3.0 s")
    result, doc = run(pytester)
    assert result.ret == 2
    assert doc["error"] == "target never answered: no Mission_Ready within 3.0 s"
    assert doc["cases"] == []
    assert [e["event"] for e in log(pytester)] == ["start", "close"]


def test_target_lost_makes_the_remaining_cases_errors(pytester):
    setup_files(pytester, lost_after=2)
    result, doc = run(pytester)
    assert result.ret == 1
    later = [c for c in doc["cases"][2:]]
    assert later and all(c["outcome"] == "error" for c in later)
    assert later[0]["reason"] == "target lost: the node went silent"


def test_per_case_time_limit(pytester):
    cases = """
    import time
    from mcp_conform.conformance.marks import rules

    @rules("MCP-ACK-1")
    def test_hangs(node):
        time.sleep(30)

    @rules("MCP-ACK-2")
    def test_after(node):
        pass
    """
    # the limit leaves a loaded machine room for test_after (and test_hangs' own setup)
    setup_files(pytester, cases, case_timeout=2.0)
    result, doc = run(pytester)
    assert result.ret == 1
    assert outcomes(doc) == {"ACK/test_hangs": "error", "ACK/test_after": "passed"}
    assert doc["cases"][0]["reason"] == "case exceeded its time limit of 2 s"
    assert "end" in [e["event"] for e in log(pytester)]


def test_run_deadline(pytester):
    cases = """
    import time
    from mcp_conform.conformance.marks import rules

    @rules("MCP-ACK-1")
    def test_first(node):
        pass

    @rules("MCP-ACK-2")
    def test_slow(node):
        time.sleep(30)

    @rules("MCP-ACK-3")
    def test_never_reached(node):
        pass
    """
    setup_files(pytester, cases)
    result, doc = run(pytester, "--mcp-timeout", "3")  # room for test_first on a loaded machine
    assert result.ret == 1
    assert outcomes(doc) == {"ACK/test_first": "passed", "ACK/test_slow": "error",
                             "ACK/test_never_reached": "error"}
    assert {c["reason"] for c in doc["cases"][1:]} == {"run deadline exceeded"}
    assert doc["error"] is None


def test_a_run_deadline_passed_before_the_node_starts_is_a_setup_error(pytester):
    """A loaded CI host (issue 19): ``mcp-conform --timeout 3`` against a silent target gave 44
    cases "run deadline exceeded" (exit 1), the deadline having passed before the first case
    started the node. Now: exit 2, no case, the error saying where the time went. The host's
    stall is a plugin sleeping before the first case."""
    setup_files(pytester, """
    from mcp_conform.conformance.marks import rules

    @rules("MCP-ACK-1")
    def test_first(node):
        pass

    @rules("MCP-ACK-2")
    def test_second(node):
        pass
    """)
    pytester.makepyfile(stall="""
    import time

    import pytest

    stalled = []

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(item, nextitem):
        if not stalled:
            stalled.append(item.nodeid)
            time.sleep(1.3)
        yield
    """)
    pytester.syspathinsert()
    result, doc = run(pytester, "-p", "stall", "--mcp-timeout", "1")
    assert result.ret == 2, result.stdout.str()
    assert doc["cases"] == [], doc["cases"]
    assert doc["error"] == ("the run's --timeout of 1 s passed before the runner reached the target "
                            "(its own start-up took all of it)"), doc["error"]
    assert log(pytester) == []  # no node was started


def test_unknown_rule_id_is_a_collection_error_naming_it(pytester):
    setup_files(pytester, CASES + '\n@rules("MCP-ACK-99")\ndef test_typo(node):\n    pass\n')
    result, doc = run(pytester)
    assert result.ret == 2
    assert "MCP-ACK-99" in doc["error"] and doc["error"].startswith("collection error")


def test_junit_report(pytester):
    setup_files(pytester)
    run(pytester, "--mcp-junit", "junit.xml")
    suite = ET.parse(pytester.path / "junit.xml").getroot().find("testsuite")
    assert suite is not None
    cases = {tc.get("name").removesuffix(" [warned]"): tc for tc in suite.iter("testcase")}
    assert set(cases) == set(ALL_IDS)
    assert [tc.get("name") for tc in suite.iter("testcase") if tc.get("name").endswith(" [warned]")] == [
        "ACK/test_should_fails [warned]"]  # a SHOULD failure is visible in every CI UI
    assert cases["ACK/test_must_fails"].find("failure") is not None
    assert cases["ROB/test_crash"].find("error") is not None
    assert cases["BLK/test_inconclusive"].find("skipped").get("message") == "MCP-BLK-2 binds the manager"
    assert cases["ACK/test_should_fails"].find("failure") is None
    assert "median 0.3 s" in cases["ACK/test_should_fails"].find("system-out").text
    assert cases["ACK/test_pass"].get("classname") == "mcp-conform.ACK"


def test_embedded_default_and_options_reach_the_session(pytester):
    setup_files(pytester)
    run(pytester, "--mcp-select", "ACK/test_pass", "--mcp-strict")
    start = log(pytester)[0]
    assert start["embedded"] is True and start["strict"] is True
    assert start["rto"] < 1.0  # the embedded default assumes the reference node's short timeouts
    run(pytester, "--mcp-select", "ACK/test_pass", "--mcp-target", "127.0.0.1:9", "--mcp-rto", "0.7")
    start = [e for e in log(pytester) if e["event"] == "start"][-1]
    assert start["embedded"] is False and start["rto"] == 0.7


def test_bad_option_value_is_a_usage_error(pytester):
    setup_files(pytester)
    result = pytester.runpytest(*PLUGIN, "--mcp-rto", "soon")
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    assert "--mcp-rto: 'soon' is not a number of seconds" in result.stderr.str()


def test_inert_without_marked_cases(pytester):
    pytester.makepyfile(test_plain="def test_ok():\n    pass\n\ndef test_bad():\n    assert 1 == 2\n")
    result = pytester.runpytest(*PLUGIN)
    assert result.ret == 1
    result.assert_outcomes(passed=1, failed=1)
    # the plugin may be listed among pytest's plugins (it is installed); it prints nothing
    out = "\n".join(ln for ln in result.stdout.lines if not ln.startswith("plugins:"))
    assert "mcp-conform" not in out and "per-rule outcome" not in out
    assert not (pytester.path / "session.log").exists()
