"""The plugin as a CI citizen (issue 13), through pytester and a fake session: beside
pytest-timeout the user's shorter ``--timeout`` wins and nothing is killed; options come
from the command line, the ini file or the environment; attach mode refuses xdist."""

from __future__ import annotations

import json
import textwrap

import pytest

from tests.forkserver import run_module

from .test_plugin import PLUGIN, log, outcomes, run, setup_files

pytest_plugins = ("pytester",)

SLOW_CASES = """
import time
from mcp_conform.conformance.marks import rules

@rules("MCP-ACK-1")
def test_slow_a(node):
    time.sleep(6)

@rules("MCP-ACK-2")
def test_slow_b(node):
    time.sleep(6)

@rules("MCP-ACK-3")
def test_quick(node):
    pass
"""


def test_user_timeout_wins_where_shorter_and_nothing_is_killed(pytester):
    pytest.importorskip("pytest_timeout")
    setup_files(pytester, SLOW_CASES)
    pytester.makeini("[pytest]\n")  # no ini timeout of our own
    result, doc = run(pytester, "-p", "timeout", "--timeout", "1", "--mcp-junit", "j.xml")
    assert result.ret == 1, result.stdout.str()  # two errors: a failed run, not a killed one
    assert outcomes(doc) == {"ACK/test_slow_a": "error", "ACK/test_slow_b": "error", "ACK/test_quick": "passed"}
    reasons = {c["id"]: c["reason"] for c in doc["cases"]}
    assert "--timeout of 1 s (pytest-timeout)" in reasons["ACK/test_slow_a"]
    assert (pytester.path / "j.xml").exists()  # pytest survived to write its reports
    assert doc["summary"]["duration_s"] < 11.5  # the two 6-s sleeps were cut short, not waited out


def test_our_case_limit_applies_where_shorter_than_the_users(pytester):
    pytest.importorskip("pytest_timeout")
    setup_files(pytester, SLOW_CASES)
    result, doc = run(pytester, "-p", "timeout", "--timeout", "30", "--mcp-case-timeout", "0.5",
                      "--mcp-select", "ACK/test_slow_a")
    assert outcomes(doc) == {"ACK/test_slow_a": "error"}
    assert "time limit of 0.5 s" in doc["cases"][0]["reason"]


def test_options_from_the_ini_file_and_the_environment(pytester, monkeypatch):
    setup_files(pytester)
    pytester.makeini(textwrap.dedent("""\
        [pytest]
        mcp_target = 127.0.0.1:9
        mcp_rto = 0.7
        mcp_strict = true
        """))
    monkeypatch.setenv("MCP_CONFORM_ACK_WINDOW", "0.3")
    monkeypatch.setenv("MCP_CONFORM_RTO", "0.9")  # the ini file comes first
    result, doc = run(pytester, "--mcp-select", "ACK/test_pass")
    start = log(pytester)[0]
    assert start["embedded"] is False and start["rto"] == 0.7 and start["strict"] is True
    assert doc["parameters"]["ack_window"] == 0.3
    result, doc = run(pytester, "--mcp-select", "ACK/test_pass", "--mcp-rto", "0.4")  # the command line first
    assert [e for e in log(pytester) if e["event"] == "start"][-1]["rto"] == 0.4


def test_a_bad_environment_value_is_a_usage_error_naming_the_option(pytester, monkeypatch):
    setup_files(pytester)
    monkeypatch.setenv("MCP_CONFORM_RTO", "fast")
    result = pytester.runpytest(*PLUGIN, "-p", "no:cacheprovider")
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    assert "--mcp-rto: 'fast' is not a number of seconds" in result.stderr.str()


def test_attach_mode_refuses_to_be_split_across_xdist_workers(pytester):
    pytest.importorskip("xdist")
    setup_files(pytester)
    result = pytester.runpytest(*PLUGIN, "-p", "no:cacheprovider", "-n", "2", "--mcp-target", "127.0.0.1:9")
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    err = result.stderr.str()
    assert "attach mode cannot be split across pytest-xdist workers" in err
    assert "keyboard" not in (result.stdout.str() + err).lower()
    assert json.dumps  # (the report of a refused run is the usage error itself)


@pytest.mark.slow
def test_verbose_prints_live_traffic_to_stderr_and_embedded_reports_the_vehicle(tmp_path):
    from .runner_helpers import ROOT

    js = tmp_path / "r.json"
    proc = run_module("conformance", ["-v", "--select", "MCP-ACK-4", "--json", str(js)], cwd=tmp_path, timeout=120,
                      env={**__import__("os").environ, "PYTHONPATH": str(ROOT), "NO_COLOR": "1"})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    lines = proc.stderr.splitlines()
    assert any(" rx ← " in ln and "MISSION_READY" in ln for ln in lines), proc.stderr
    assert any(" tx → " in ln and " ACK " in ln for ln in lines), proc.stderr
    assert "startup phase" in proc.stdout and "MISSION_READY" not in proc.stdout
    doc = json.loads(js.read_text())
    assert doc["parameters"]["mavlink"] is True and doc["parameters"]["mode"] == "embedded"


def test_mcp_node_version():
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", "mcp_conform.reference_impl", "--version"], capture_output=True, text=True)
    assert proc.returncode == 0 and proc.stdout.startswith("mcp-node ") and "MCP spec" in proc.stdout


INERT_CONFTEST = """
import sys

def pytest_sessionfinish(session):
    pm = session.config.pluginmanager
    with open("inert.txt", "w") as f:
        f.write(f"{pm.has_plugin('mcp_conform.conformance._plugin_run')} {'mcp_conform.spec' in sys.modules} "
                f"{'mcp_conform.conformance._plugin_run' in sys.modules}")
"""


def test_the_plugin_loads_nothing_when_no_option_asks_for_it(tmp_path):
    """Installed for every pytest run, the entry point registers the runner, and imports the
    spec, only when an --mcp-* option, ini key or MCP_CONFORM_* variable asks for it."""
    import os
    import subprocess
    import sys

    (tmp_path / "conftest.py").write_text(INERT_CONFTEST)
    (tmp_path / "test_plain.py").write_text("def test_ok():\n    assert True\n")
    env = {k: v for k, v in os.environ.items() if not k.startswith("MCP_CONFORM_")}

    def run(*args: str) -> str:
        proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *args],
                              cwd=tmp_path, capture_output=True, text=True, env=env, timeout=120)
        assert proc.returncode == 0, proc.stdout + proc.stderr
        return (tmp_path / "inert.txt").read_text()

    assert run() == "False False False"
    assert run("--mcp-rto", "0.5") == "True True True"


def _verdicts(path, name_of) -> dict[str, str]:
    """testcase name -> failure | error | skipped | passed, from a JUnit file."""
    import xml.etree.ElementTree as ET

    out = {}
    for tc in ET.parse(path).getroot().iter("testcase"):
        tags = [t.tag for t in tc if t.tag in ("failure", "error", "skipped")]
        out[name_of(tc)] = tags[0] if tags else "passed"
    return out


def test_a_timeout_is_an_error_in_pytests_junit_as_in_ours(pytester):
    """Issue 18 item 14: one verdict for a case that runs out of time (pytest-timeout's
    --timeout or the runner's own limit) and for a case that crashed: ``<error>`` in
    pytest's --junitxml, as in --mcp-junit and the JSON report; a MUST failure stays a
    ``<failure>`` in both."""
    pytest.importorskip("pytest_timeout")
    # --timeout 3 and an 8-s sleep (the node's startup is not charged to the first case; the
    # third error a loaded host once gave was the next case's: the timed-out case's teardown
    # was cut short, see test_a_timed_out_case_is_torn_down_within_its_grace_and_the_next_starts_clean)
    cases = SLOW_CASES.replace("time.sleep(6)", "time.sleep(8)") + """
@rules("MCP-ACK-4")
def test_must_fails(node):
    from mcp_conform.harness.errors import CaseFailure
    raise CaseFailure("MCP-ACK-4", "no ACK", "an ACK of seq 3")

@rules("MCP-ROB-1")
def test_crash(node):
    raise RuntimeError("boom")
"""
    setup_files(pytester, cases)
    pytester.makeini("[pytest]\n")
    result, doc = run(pytester, "-p", "timeout", "--timeout", "3", "--mcp-case-timeout", "30",
                      "--mcp-select", "ACK/test_slow_a", "--mcp-select", "ACK/test_must", "--mcp-select", "ROB",
                      "--mcp-junit", "ours.xml", "--junitxml", "pytests.xml")
    assert outcomes(doc) == {"ACK/test_slow_a": "error", "ACK/test_must_fails": "failed", "ROB/test_crash": "error"}
    ours = _verdicts(pytester.path / "ours.xml", lambda tc: tc.get("name"))
    theirs = _verdicts(pytester.path / "pytests.xml", lambda tc: tc.get("name"))
    assert ours == {"ACK/test_slow_a": "error", "ACK/test_must_fails": "failure", "ROB/test_crash": "error"}
    assert theirs == {"test_slow_a": "error", "test_must_fails": "failure", "test_crash": "error"}
    import xml.etree.ElementTree as ET

    suite = ET.parse(pytester.path / "pytests.xml").getroot().find("testsuite")
    assert (suite.get("errors"), suite.get("failures")) == ("2", "1")
    result.assert_outcomes(failed=1, errors=2)


SLOW_NODE = """
import pytest

START_S, BEGIN_S, END_S, BUSY_S, GRACE_S = {start!r}, {begin!r}, {end!r}, {busy!r}, {grace!r}
if GRACE_S is not None:
    import mcp_conform.conformance._plugin_run  # noqa: F401  (the attribute the next line's name reaches)
    from mcp_conform import conformance
    conformance._plugin_run.TEARDOWN_GRACE_S = GRACE_S
_start, _begin, _end = FakeSession.start, FakeSession.begin_case, FakeSession.end_case

def _slow_start(self):  # the node's startup (the first case's setup) outlasts --timeout
    time.sleep(START_S)
    _start(self)

def _slow_begin(self, case_id, rules):  # the first case's own setup outlasts --timeout
    if not getattr(self, "slowed", False):
        self.slowed = True
        time.sleep(BEGIN_S)
    return _begin(self, case_id, rules)

def _slow_end(self, ctx, outcome):  # the first case's end takes time (the node quieted)
    if not getattr(self, "ended_one", False):
        self.ended_one = True
        time.sleep(END_S)
    _end(self, ctx, outcome)

FakeSession.start, FakeSession.begin_case, FakeSession.end_case = _slow_start, _slow_begin, _slow_end

@pytest.hookimpl(wrapper=True, trylast=True)
def pytest_runtest_teardown(item, nextitem):
    time.sleep(BUSY_S)  # a loaded host: the plugins' own steps before pytest's teardown take time
    return (yield)
"""

TWO_CASES = """
import time
from mcp_conform.conformance.marks import rules

@rules("MCP-ACK-1")
def test_slow(node):
    time.sleep({sleep!r})

@rules("MCP-ACK-3")
def test_next(node):
    pass
"""


def _slow_node_run(pytester, *, sleep=5.0, start=0.0, begin=0.0, end=0.2, busy=0.02, grace=None):
    from .test_plugin import CONFTEST

    pytester.makeconftest(CONFTEST.format(setup_error=None, lost_after=None, case_timeout=None)
                          + SLOW_NODE.format(start=start, begin=begin, end=end, busy=busy, grace=grace))
    pytester.makepyfile(test_fake=TWO_CASES.format(sleep=sleep))
    pytester.makeini("[pytest]\n")
    result, doc = run(pytester, "-p", "timeout", "--timeout", "1", "--mcp-case-timeout", "30",
                      "--junitxml", "pytests.xml")
    out = result.stdout.str()
    assert "not torn down properly" not in out, out
    assert outcomes(doc) == {"ACK/test_slow": "error", "ACK/test_next": "passed"}, out
    theirs = _verdicts(pytester.path / "pytests.xml", lambda tc: tc.get("name"))
    assert theirs["test_next"] == "passed", out
    return result, doc, {c["id"]: c["reason"] for c in doc["cases"]}


def test_a_timed_out_case_is_torn_down_within_its_grace_and_the_next_starts_clean(pytester):
    """A case that ran out of time (its call) is an error with the reason; its teardown (the
    node fixture's end of the case: 0.2 s) gets a grace period of its own, not the
    limit that has already run out (it was armed for 1 ms: the alarm struck in pytest's
    teardown, the node's end of the case never ran and the NEXT case errored, "previous item
    was not torn down properly"). The node's startup, longer than --timeout, is not charged to
    the first case."""
    pytest.importorskip("pytest_timeout")
    result, doc, reasons = _slow_node_run(pytester, start=1.5)
    assert "--timeout of 1 s (pytest-timeout)" in reasons["ACK/test_slow"]
    out = result.stdout.str()
    assert "ERROR at call of test_slow" in out and "ERROR at setup of test_slow" not in out, out
    assert "teardown" not in reasons["ACK/test_slow"]
    ends = [(e["case"], e["outcome"]) for e in log(pytester) if e["event"] == "end"]
    assert ends == [("ACK/test_slow", "error"), ("ACK/test_next", "passed")]
    result.assert_outcomes(passed=1, errors=1)  # no teardown error beside the timeout


def test_a_case_timed_out_in_its_setup_is_torn_down_and_the_next_starts_clean(pytester):
    pytest.importorskip("pytest_timeout")
    result, doc, reasons = _slow_node_run(pytester, sleep=0.0, begin=3.0)
    assert "--timeout of 1 s (pytest-timeout)" in reasons["ACK/test_slow"]
    ends = [(e["case"], e["outcome"]) for e in log(pytester) if e["event"] == "end"]
    assert ends == [("ACK/test_next", "passed")]  # the slow case's node context never began
    result.assert_outcomes(passed=1, errors=1)


def test_a_teardown_overrunning_its_grace_is_reported_on_its_own_case(pytester):
    pytest.importorskip("pytest_timeout")
    result, doc, reasons = _slow_node_run(pytester, end=5.0, grace=0.5)
    assert "--timeout of 1 s (pytest-timeout)" in reasons["ACK/test_slow"]
    assert "teardown overran its grace of 0.5 s" in reasons["ACK/test_slow"]
    ends = [(e["case"], e["outcome"]) for e in log(pytester) if e["event"] == "end"]
    assert ends == [("ACK/test_next", "passed")]  # the slow case's end was cut short
