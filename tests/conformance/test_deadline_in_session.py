"""The run's --timeout falling before the node's startup ended -- wherever its SIGALRM strikes:
the first case's setup, the session's making (its recorder, sockets, imports), the startup -- is
a setup error: exit 2, one line naming the --timeout, a report that holds no case, the capture
valid; never each case an error. Once the startup ended it ends the cases not run ("run
deadline exceeded"), as before.

CI run 50 and later (a fresh clone beside other jobs): ``test_faults::test_bad_addresses_are_setup_errors[--timeout
of 3 s]`` exited 2 with the setup error's one line but a report of 44 cases in error, "run
deadline exceeded": the ``mcp_session`` fixture armed the alarm again (the deadline past, 1 ms)
as the setup error's exit went through it, and it struck before the case's wrapper disarmed it.

In-process, as the simulator runs the suite, deterministically: a step strikes by setting the
run's deadline to now and arming, and the arm of a deadline already past waits for its SIGALRM
(``_alarm_at_once``: a loaded host, where the next line comes after the alarm)."""

from __future__ import annotations

import signal
import time
from pathlib import Path
from typing import Any

import pytest

from mcp_conform.conformance import _run_state, cli, run_display
from mcp_conform.conformance._run_state import McpState, state_of
from mcp_conform.spec.profiles import pick
from mcp_conform.traceio.recorder import McapRecorder
from tests.capturing import free_port

from .fault_helpers import read_mcap, read_report

TIMEOUT = 30  # the run's --timeout: only the steps below make it pass


@pytest.fixture(autouse=True)
def _alarm_at_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """``McpState.arm`` of a deadline already past (its 1-ms timer) returns only once its SIGALRM
    struck (the handler raising in here), as on a loaded host: the CI failure's timing, every run."""
    arm = McpState.arm

    def at_once(self: McpState) -> None:
        arm(self)
        if not 0 < signal.getitimer(signal.ITIMER_REAL)[0] <= 0.0015:
            return
        end = time.monotonic() + 5.0
        while signal.getitimer(signal.ITIMER_REAL)[0] > 0 and time.monotonic() < end:
            time.sleep(0.0005)

    monkeypatch.setattr(McpState, "arm", at_once)


class _Run:
    """A plugin: the run's state for the steps, and where the alarm struck."""

    def __init__(self) -> None:
        self.state: McpState | None = None
        self.struck: list[str] = []

    def pytest_sessionstart(self, session: pytest.Session) -> None:
        self.state = state_of(session.config)

    def strike(self, step: str) -> None:
        """The run's deadline now: its SIGALRM strikes in this step (``_alarm_at_once``)."""
        if self.struck or self.state is None:
            return
        self.struck.append(step)
        self.state.run_deadline = time.monotonic()
        self.state.arm()


def _after(run: _Run, step: str, fn: Any) -> Any:
    def wrapped(*args: Any, **kwargs: Any) -> Any:
        out = fn(*args, **kwargs)
        run.strike(step)
        return out
    return wrapped


def _before(run: _Run, step: str, fn: Any) -> Any:
    def wrapped(*args: Any, **kwargs: Any) -> Any:
        run.strike(step)
        return fn(*args, **kwargs)
    return wrapped


class _InSetup:
    """The first case's setup, inside the runner's armed wrapper, before its fixtures."""

    def __init__(self, run: _Run) -> None:
        self.run = run

    def pytest_runtest_setup(self, item: pytest.Item) -> None:
        self.run.strike("the first case's setup")


class _InCall(_InSetup):
    """The first case's call: the node's startup has ended."""

    def pytest_runtest_setup(self, item: pytest.Item) -> None:
        pass

    def pytest_runtest_call(self, item: pytest.Item) -> None:
        self.run.strike("the first case's call")


class _MakeSession:
    """The session made (its sockets open), before the runner holds it; or its startup's start."""

    def __init__(self, run: _Run, startup: bool) -> None:
        self.run, self.startup = run, startup

    @pytest.hookimpl(wrapper=True)
    def pytest_mcp_make_session(self, cfg: Any, recorder: Any, config: Any) -> Any:
        session = yield
        if not self.startup:
            self.run.strike("the session's making")
        elif session is not None:
            session.start = _before(self.run, "the startup", session.start)
        return session


class _AtRunStart:
    """The deadline passed by the first case (pytest's collection's end, the header): no alarm is
    armed yet there."""

    def __init__(self, run: _Run) -> None:
        self.run = run

    def pytest_runtestloop(self, session: pytest.Session) -> None:
        state = self.run.state
        assert state is not None and state.run_deadline is not None
        self.run.struck.append("the collection's end")
        state.run_deadline = time.monotonic() - 0.001


def _patch(step: str, run: _Run, monkeypatch: pytest.MonkeyPatch) -> list[Any]:
    """The plugins (and patches) that make the run's deadline strike in ``step``."""
    if step == "the collection's end":
        return [_AtRunStart(run)]
    if step == "the first case's setup":
        return [_InSetup(run)]
    if step == "the first case's call":
        return [_InCall(run)]
    if step in ("the session's making", "the startup"):
        return [_MakeSession(run, step == "the startup")]
    if step == "the session fixture":
        monkeypatch.setattr(McpState, "start_session", _before(run, step, McpState.start_session))
    elif step == "the embedded defaults":
        monkeypatch.setattr(_run_state, "apply_embedded_defaults", _after(run, step, _run_state.apply_embedded_defaults))
    elif step == "the live server":
        monkeypatch.setattr(McpState, "start_live", _after(run, step, McpState.start_live))
    elif step == "the recorder":  # inside its making: the file's header written
        monkeypatch.setattr(McapRecorder, "_register_channels", _after(run, step, McapRecorder._register_channels))
    elif step == "the display's import":
        monkeypatch.setattr(run_display, "FirstDatagram", _before(run, step, run_display.FirstDatagram))
    elif step == "the profile":
        monkeypatch.setattr(_run_state, "resolve", _before(run, step, _run_state.resolve))
    elif step == "the node check":
        monkeypatch.setattr(_run_state, "check_node", _after(run, step, _run_state.check_node))
    elif step == "just after the startup":  # start_session's first limit for the cases, the node up
        limit = McpState.current_limit

        def current_limit(self: McpState) -> float:
            if self.session is not None:
                run.strike(step)
            return limit(self)
        monkeypatch.setattr(McpState, "current_limit", current_limit)
    else:
        raise AssertionError(step)
    return []


def _conform(argv: list[str], plugins: list[Any]) -> int:
    ns = cli.build_parser().parse_args(argv)
    ns.protocol, ns.role = (p.name for p in pick("mcp", "drone"))
    with cli._quiet(True):
        return cli.run_pytest(cli.pytest_args(ns), plugins)


BEFORE_THE_STARTUP_ENDED = [
    "the collection's end", "the first case's setup", "the session fixture", "the embedded defaults",
    "the live server", "the recorder", "the display's import", "the profile", "the session's making",
    "the node check", "the startup",
]
RECORDING = BEFORE_THE_STARTUP_ENDED.index("the recorder")


@pytest.mark.parametrize("step", BEFORE_THE_STARTUP_ENDED)
def test_the_run_deadline_before_the_startup_ended_is_a_setup_error(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], step: str) -> None:
    """Exit 2, one line on stderr naming the run's --timeout, a valid report of no case, the
    capture (asked) valid wherever it was begun: before the fix "the startup" (the CI failure)
    and "the first case's setup" left 44 cases in error, "the recorder" a capture cut off after
    its header."""
    run = _Run()
    plugins = [run, *_patch(step, run, monkeypatch)]
    path, cap = tmp_path / "r.json", tmp_path / "r.mcap"
    argv = ["--target", f"127.0.0.1:{free_port()}", "--listen", "127.0.0.1:0", "--timeout", str(TIMEOUT),
            "--json", str(path), "--capture", str(cap), "--quiet"]
    t0 = time.monotonic()
    rc = _conform(argv, plugins)
    took = time.monotonic() - t0
    err = capsys.readouterr().err
    assert run.struck == [step], run.struck
    doc = read_report(path)  # valid against the report's schema
    cases = [(c["id"], c["reason"]) for c in doc["cases"]]
    assert rc == 2 and doc["cases"] == [], (step, rc, doc["error"], len(cases), cases[:3], err)
    assert doc["error"] is not None and f"--timeout of {TIMEOUT} s" in doc["error"], doc["error"]
    lines = err.strip().splitlines()
    assert len(lines) == 1 and f"--timeout of {TIMEOUT} s" in lines[0] and "Traceback" not in err, err
    assert doc["summary"]["error"] == 0, doc["summary"]
    if BEFORE_THE_STARTUP_ENDED.index(step) >= RECORDING:
        read_mcap(cap)  # its footer written: nothing lost
    else:
        assert not cap.exists()
    assert took < TIMEOUT, took  # the deadline struck, not the run's own --timeout


@pytest.mark.parametrize("step", ["just after the startup", "the first case's call"])
def test_the_run_deadline_once_the_startup_ended_ends_the_cases(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, step: str) -> None:
    """Once the node's startup ended (the embedded reference node), the run's deadline ends the
    cases not run, each an error "run deadline exceeded", exit 1, no setup error: as before the
    fix (which made "just after the startup" a setup error, a node that had answered said
    never to have)."""
    run = _Run()
    plugins = [run, *_patch(step, run, monkeypatch)]
    path = tmp_path / "r.json"
    argv = ["--rto", "0.2", "--ack-window", "0.25", "--select", "MCP-ACK-2", "MCP-ACK-3",
            "--timeout", str(TIMEOUT), "--json", str(path), "--quiet"]
    rc = _conform(argv, plugins)
    assert run.struck == [step], run.struck
    doc = read_report(path)  # valid against the report's schema
    assert doc["error"] is None and rc == 1, (rc, doc["error"])
    assert len(doc["cases"]) == 2, doc["cases"]
    assert {(c["outcome"], c["reason"]) for c in doc["cases"]} == {("error", "run deadline exceeded")}, doc["cases"]


def test_the_run_deadline_while_the_session_is_made_is_a_setup_error(tmp_path: Path) -> None:
    """A plugin's ``pytest_mcp_make_session`` takes longer than the run's --timeout, as a loaded
    host did (CI run 50): the real deadline's SIGALRM, no step made to strike."""

    class SlowToMake:
        @pytest.hookimpl(tryfirst=True)
        def pytest_mcp_make_session(self, cfg, recorder, config):  # type: ignore[no-untyped-def]
            end = time.monotonic() + 2.5
            while time.monotonic() < end:  # the run deadline's SIGALRM strikes in here
                time.sleep(0.05)

    path = tmp_path / "r.json"
    argv = ["--target", f"127.0.0.1:{free_port()}", "--listen", "127.0.0.1:0", "--timeout", "1",
            "--json", str(path), "--quiet"]
    rc = _conform(argv, [SlowToMake()])
    doc = read_report(path)  # valid against the report's schema
    assert rc == 2 and doc["cases"] == [], (rc, doc.get("error"), [c["reason"] for c in doc["cases"]][:3])
    assert "--timeout of 1 s" in doc["error"], doc["error"]
