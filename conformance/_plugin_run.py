"""The runner inside pytest (registered by ``conformance.plugin`` when a run asks for it).

It holds the hooks and fixtures (``mcp_config``, ``mcp_session``, ``node``), the MUST /
SHOULD / INFO outcome mapping, per-case and per-run time limits (the run's state is
``conformance._run_state.McpState``), and the reports (terminal,
``--mcp-json``, ``--mcp-junit``, ``--mcp-html``, ``--mcp-capture``; merged by the
controller under pytest-xdist). It is inert for any run that collects no case marked with
``rules(...)``.

Outcomes: a pass is ``passed`` (``info`` when every rule of the case is INFO); a
``CaseFailure`` takes the level of the rule it names: MUST -> failed, SHOULD -> warned
(the pytest report becomes a pass) unless ``--mcp-strict``, INFO -> info; ``Inconclusive``
-> skipped with its reason; ``TargetLost``, a time limit and any other exception -> error.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Generator
from typing import Any

import pytest

from mcp_conform.conformance._run_reports import (
    hand_to_controller,
    merge_worker_reports,
    write_run_reports,
)
from mcp_conform.conformance._run_state import (
    STATE_KEY,
    CaseTimeLimit,
    McpState,
    _meta,
    _one_line,
    state_of,
)
from mcp_conform.conformance._verdicts import apply_baseline as _apply_baseline
from mcp_conform.conformance._verdicts import exception_only as _exception_only
from mcp_conform.conformance._verdicts import judge_exception as _judge_exception
from mcp_conform.conformance._verdicts import log_evidence as _log_evidence
from mcp_conform.conformance._verdicts import verdict_repr as _verdict_repr
from mcp_conform.conformance.baseline import BaselineError, load_baseline
from mcp_conform.conformance.junit import as_pytest_error
from mcp_conform.conformance.marks import (
    PHASES,
    is_case,
    rule_level,
    rule_marker,
)
from mcp_conform.conformance.options import (
    ConfigError,
    make_config,
    matches_select,
    option_values,
    unmatched,
)
from mcp_conform.conformance.report import (
    case_from_json,
    worker_path,
)
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.errors import (
    CaseFailure,
    Inconclusive,
)
from mcp_conform.harness.interrupts import INTERRUPTS
from mcp_conform.spec import RULES
from mcp_conform.spec.profiles import resolve

__all__ = ["McpState", "STATE_KEY", "TEARDOWN_GRACE_S"]
_state = state_of

#: A case's teardown (the node fixture's end of the case; after the last case, the node
#: stopped: up to 2 s after SIGTERM, 2 more after SIGKILL) always has at least this long, even
#: when the case ran out of time: the next case then starts clean.
TEARDOWN_GRACE_S = 10.0


@pytest.hookimpl(trylast=True)
def pytest_mcp_make_session(cfg: RunConfig, recorder: Any, config: pytest.Config) -> Any:
    """The node under test of the run's protocol and role, as its profile names it
    (``spec.profiles``): its session, handed its case context."""
    role = cfg.profile()[1]
    context = resolve(role.context)
    session = resolve(role.session)(cfg, recorder=recorder)
    session.make_context = context
    state = _state(config)  # what the role's cases need of it (a manager's overlapping scenarios)
    context.prepare_session(session, config, state.items if state is not None else [])
    return session


def pytest_configure(config: pytest.Config) -> None:
    _PLUGIN_CONFIG["config"] = config
    config.addinivalue_line("markers", "mcp_rules(*ids): the MCP rule IDs a conformance case verifies")
    config.addinivalue_line("markers", "mcp_phase(phase): startup, main, late or end")
    for rule in RULES.values():
        config.addinivalue_line("markers", f"{rule_marker(rule.id)}: cases verifying {rule.id} ({rule.level})")
    frontend = bool(config.getoption("mcp_frontend"))
    values = option_values(config)
    opt = (lambda n: "--" + n.replace("_", "-")) if frontend else (lambda n: "--mcp-" + n.replace("_", "-"))
    try:
        cfg = make_config(values, opt)
    except ConfigError as exc:
        raise pytest.UsageError(str(exc)) from None
    if cfg.target is not None and int(getattr(config.option, "numprocesses", 0) or 0) > 1 \
            and not hasattr(config, "workerinput"):
        raise pytest.UsageError(
            f"{opt('target')}: attach mode cannot be split across pytest-xdist workers (one node "
            "under test, one runner at a time); run it without -n, or let each worker start its own "
            "node with --mcp-spawn")
    worker = getattr(config, "workerinput", {}).get("workerid")
    if worker:  # a pytest-xdist worker: its own node; its report goes to the controller
        cfg.capture = cfg.capture and worker_path(cfg.capture, worker)
    family = config.getoption("mcp_junit_family") or "xunit2"
    if family not in ("xunit2", "xunit1"):
        raise pytest.UsageError(f"{opt('junit_family')}: {family!r} is not one of xunit2, xunit1")
    baseline = None
    if config.getoption("mcp_baseline"):
        try:
            baseline = load_baseline(config.getoption("mcp_baseline"), opt("baseline"))
        except BaselineError as exc:
            raise pytest.UsageError(str(exc)) from None
    state = config.stash[STATE_KEY] = McpState(config, cfg, frontend)
    state.baseline, state.junit_family = baseline, family
    state.write_baseline_path = config.getoption("mcp_write_baseline")
    state.exclude = list(config.getoption("mcp_exclude") or [])
    state.worker = worker
    state.html_path = config.getoption("mcp_html")  # under xdist the controller writes it
    try:
        state.set_shard(config.getoption("mcp_shard"), config.getoption("mcp_shard_events"))
    except ValueError as exc:
        raise pytest.UsageError(f"--mcp-shard: {exc}") from None



def _xdist_controller(config: pytest.Config) -> bool:
    return (not hasattr(config, "workerinput") and config.pluginmanager.hasplugin("xdist")
            and bool(getattr(config.option, "numprocesses", None)))


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node: Any, error: Any) -> None:
    """pytest-xdist: a worker finished; keep its report and its capture part (the
    ``workeroutput`` channel pytest-cov uses for its data)."""
    state = _state(node.config)
    out = getattr(node, "workeroutput", None) or {}
    if state is None:
        return
    if "mcp_report" in out:
        state.worker_docs.append(out["mcp_report"])
    if out.get("mcp_capture_part"):
        state.capture_parts.append(out["mcp_capture_part"])


# ---------------------------------------------------------------------- collection
@pytest.hookimpl(wrapper=True)
def pytest_make_collect_report(collector: pytest.Collector) -> Generator[None, pytest.CollectReport, pytest.CollectReport]:
    report = yield
    state = _state(collector.config)
    if state is not None and report.failed:
        text = report.longreprtext or ""
        lines = [ln[1:].strip() for ln in text.splitlines() if ln.startswith("E ")]
        msg = lines[-1] if lines else (text.strip().splitlines() or ["collection failed"])[-1]
        state.collect_errors.append(f"collection error in {report.nodeid or 'the cases'}: {msg}")
    return report


def pytest_collection_modifyitems(session: pytest.Session, config: pytest.Config, items: list[pytest.Item]) -> None:
    state = _state(config)
    if state is None:
        return
    cases = [i for i in items if is_case(i)]
    state.active = bool(cases) or state.frontend or bool(state.cfg.json_path or state.cfg.junit_path)
    if not cases:
        return
    for item in cases:
        item.repr_failure = _verdict_repr(item.repr_failure)  # type: ignore[method-assign]
        if state.frontend:  # setup's and teardown's exceptions too (pytest calls this for them)
            item._repr_failure_py = _exception_only  # type: ignore[method-assign,assignment]  # a str: as repr_failure's
        cid, ids, level, phase = _meta(item)
        unknown = [r for r in ids if r not in RULES]
        if unknown:
            state.collect_errors.append(f"unknown rule ID {unknown[0]!r} in {cid}")
        state.meta[item.nodeid] = (cid, ids, level, phase)
    stray = unmatched(state.exclude, ((m[0], m[1]) for m in state.meta.values()))
    if stray:  # as --select does: a typo is said, not a case silently run
        state.collect_errors.append(f"{'--exclude' if state.frontend else '--mcp-exclude'}: "
                                    f"no case matches {', '.join(stray)}")
    if state.collect_errors:
        return
    keep: list[pytest.Item] = []
    drop: list[pytest.Item] = []
    for item in items:
        m = state.meta.get(item.nodeid)
        wanted = m is None or (matches_select(state.select, m[0], m[1])
                               and not (state.exclude and matches_select(state.exclude, m[0], m[1])))
        (keep if wanted else drop).append(item)
    if drop:
        config.hook.pytest_deselected(items=drop)
    if (state.select or state.exclude) and not any(i.nodeid in state.meta for i in keep):
        opt = "--select" if state.frontend else "--mcp-select"
        what = ", ".join(state.select) if state.select else "(all)"
        if state.exclude:
            what += f" once {', '.join(state.exclude)} are excluded"
        state.run.error = f"{opt}: no case matches {what}"
    order = {p: n for n, p in enumerate(PHASES)}
    keep.sort(key=lambda i: order[state.meta[i.nodeid][3]] if i.nodeid in state.meta else order["main"])
    from mcp_conform.conformance._batch import in_plan_order

    state.serial_order = list(keep)  # a batch thrown away: the rest of the run goes back to it
    items[:] = in_plan_order(state, keep)
    if state.shard is not None:  # mcp-conform --parallel: this instance's share of the plan
        state.take_shard(items)
    state.items = [i for i in items if i.nodeid in state.meta]


@pytest.hookimpl(tryfirst=True)
def pytest_runtestloop(session: pytest.Session) -> bool | None:
    state = _state(session.config)
    if state is None or not state.active:
        return None
    if state.collect_errors and state.run.error is None:
        state.run.error = state.collect_errors[0]
    if state.run.error is not None:
        raise session.Interrupted(state.run.error)
    if session.config.option.collectonly:
        return None
    if state.list_mode:
        state.terminal.listing([state.meta[i.nodeid] for i in state.items])
        return True
    if not state.items:
        return None
    mode = state.cfg.mode
    state.terminal.header(state.run, mode)
    if state.plan is not None and session.config.getoption("mcp_verbose_traffic"):
        for line in state.plan.lines():  # -v: the schedule, before the traffic
            state.terminal.note(line)
    state.run_deadline = time.monotonic() + state.cfg.timeout
    state.install_term()
    return None


# ---------------------------------------------------------------------- running a case
@pytest.hookimpl(tryfirst=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> bool | None:
    state = _state(item.config)
    if state is None or not state.active or item.nodeid not in state.meta:
        return None
    if INTERRUPTS.interrupted:  # a swallowed KeyboardInterrupt must still stop the run
        raise KeyboardInterrupt(INTERRUPTS.signals[0])
    if state.deadline_hit or (state.run_deadline is not None and time.monotonic() >= state.run_deadline):
        if not state.started:  # the node's startup never ended: a setup error, no case
            state.fail_setup(CaseTimeLimit("run deadline exceeded"))
        state.deadline_hit = True
        rec = state.record(item)
        rec.outcome, rec.reason = "error", "run deadline exceeded"
        state.finish(item, rec)
        item.session.shouldstop = "run deadline exceeded"
        return True
    state.case_user_timeout = state.user_timeouts.pop(item.nodeid, None)
    state.case_deadline = time.monotonic() + state.current_limit()
    state.wait_status.begin(state.meta[item.nodeid][0])
    return None


@pytest.hookimpl(optionalhook=True)
def pytest_timeout_set_timer(item: pytest.Item, settings: Any) -> bool | None:
    """pytest-timeout's hook for plugins that manage their own timer: for a conformance
    case the runner's SIGALRM limit becomes the shorter of its own and the user's
    ``--timeout``, and the case ends as ``error`` instead of the process being killed."""
    state = _state(item.config)
    if state is None or not state.active or item.nodeid not in state.meta:
        return None
    timeout = getattr(settings, "timeout", None)
    if timeout and timeout > 0:
        state.user_timeouts[item.nodeid] = float(timeout)
    return True


@pytest.hookimpl(optionalhook=True)
def pytest_timeout_cancel_timer(item: pytest.Item) -> bool | None:
    state = _state(item.config)
    if state is None or not state.active or item.nodeid not in state.meta:
        return None
    return True  # the runner's own timer is disarmed after each phase


def _phase_wrapper(item: pytest.Item) -> McpState | None:
    state = _state(item.config)
    if state is None or not state.active or item.nodeid not in state.meta:
        return None
    return state


def _armed(item: pytest.Item, *, teardown: bool = False, conclude: bool = False) -> Generator[None, None, None]:
    """Run one phase (setup, call, teardown) of a case under the per-case time limit; the
    teardown never with less than TEARDOWN_GRACE_S (``McpState.arm_teardown``). With
    ``conclude``, a case that passed or was skipped then runs its context's ``conclude()``
    (the Nsqd backend proven alive after the case's writes, NSQD-ROB-1: a death on them is
    this case's verdict, not the next case's), whose failure is the case's."""
    state = _phase_wrapper(item)
    if state is None:
        return (yield)
    if teardown:
        state.arm_teardown(TEARDOWN_GRACE_S)
    else:
        state.arm()
    try:
        try:
            out = yield
        except CaseTimeLimit as exc:  # the run's deadline in the first case's setup: a setup error
            if not teardown and not state.started and state.deadline_hit:
                state.fail_setup(exc)
            raise
        except Inconclusive:
            if conclude:
                _conclude(state, item)
            raise
        if conclude:
            _conclude(state, item)
        return out
    finally:
        state.grace_deadline = None
        state.disarm()


def _conclude(state: McpState, item: pytest.Item) -> None:
    ctx = state.ctx.get(item.nodeid)
    if ctx is not None:
        ctx.conclude()


@pytest.hookimpl(wrapper=True)
def pytest_runtest_setup(item: pytest.Item) -> Generator[None, None, None]:
    return (yield from _armed(item))


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item: pytest.Item) -> Generator[None, None, None]:
    state = _phase_wrapper(item)
    why = state.session.not_judged(state.meta[item.nodeid][1]) \
        if state is not None and state.session is not None else None
    if why:  # the node's datagrams cannot be read (harness.drone_session: MCP-HDR-2 at startup)
        raise Inconclusive(why)
    if state is None or state.cfg.impair is None:
        return (yield from _armed(item, conclude=True))
    from mcp_conform.conformance._impaired import SPOILABLE, run_impaired

    try:
        out = yield from _armed(item)  # type: ignore[func-returns-value]  # the inner hook's result
    except SPOILABLE as exc:  # --impair: repeated when the impairment spoiled it (never failed)
        return run_impaired(state, item, exc)
    ctx = state.ctx.get(item.nodeid)
    if getattr(ctx, "unjudged", None):  # passed on what it could judge: repeated when touched
        run_impaired(state, item, None)
    return out


@pytest.hookimpl(tryfirst=True)
def pytest_pyfunc_call(pyfuncitem: pytest.Function) -> bool | None:
    """The schedule's batch (``conformance._batch``): its first case runs them all; each case
    then takes its own verdict. A batch thrown away runs its cases alone, at their turn."""
    state = _phase_wrapper(pyfuncitem)
    if state is None or pyfuncitem not in state.batch_items:
        return None
    from mcp_conform.conformance import _batch

    batch = state.batch
    if batch.kept is None:  # the first case of the batch: all of them, together
        state.case_deadline = time.monotonic() + 2 * state.current_limit()
        state.arm()
        try:
            _batch.run_batch(state, pyfuncitem, state.batch_items, batch)
        finally:
            if state.plan is not None:
                state.plan.batch_outcome = ("kept" if batch.kept else
                                            f"thrown away, its cases ran alone: {batch.why}")
                state.run.schedule = state.plan.to_json()
            if not batch.kept:
                _batch.serial_from_here(pyfuncitem, state.serial_order)
        if not batch.kept:
            _batch.rerun_leader(state, pyfuncitem, batch)
            return True
    if batch.kept:
        _batch.take(pyfuncitem, batch)
        return True
    return None


@pytest.hookimpl(wrapper=True)
def pytest_runtest_teardown(item: pytest.Item, nextitem: pytest.Item | None) -> Generator[None, None, None]:
    return (yield from _armed(item, teardown=True))


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Generator[None, pytest.TestReport, pytest.TestReport]:
    rep = yield
    state = _state(item.config)
    if state is None or not state.active or item.nodeid not in state.meta:
        return rep
    rec = state.record(item)
    if call.when in ("setup", "call"):
        rec.duration_s += rep.duration
    if call.when == "setup" or call.when == "call":
        if call.excinfo is not None and rec.outcome not in ("error",):
            exc = call.excinfo.value
            if rep.skipped and not isinstance(exc, Inconclusive):
                rec.outcome = "skipped"
                lr = rep.longrepr
                rec.reason = str(lr[2]).removeprefix("Skipped: ") if isinstance(lr, tuple) else str(exc)
            elif call.when == "setup" and isinstance(exc, CaseFailure):
                rec.outcome, rec.reason = "error", f"setup: {_one_line(exc)}"
            else:
                _judge_exception(state, item, rec, exc, rep)
        elif call.when == "call" and call.excinfo is None:
            rec.outcome = "info" if all(rule_level(r) == "INFO" for r in rec.rules) else "passed"
        if call.when == "call" and state.baseline is not None:
            _apply_baseline(state, rec, rep)
        if call.when == "call" and rec.outcome == "error" and rep.failed:
            rep.mcp_outcome = "error"  # type: ignore[attr-defined]  # pytest's view: an error too
    elif call.when == "teardown":
        texc = call.excinfo.value if call.excinfo is not None else None
        why = (str(texc) if isinstance(texc, CaseTimeLimit) else
               f"teardown: {_one_line(texc) if texc is not None else 'failed'}")
        if rep.failed and rec.outcome not in ("error", "failed"):
            rec.outcome, rec.reason = "error", why
        elif rep.failed and rec.outcome == "error" and why not in (rec.reason or ""):
            rec.reason = f"{rec.reason}; {why}" if rec.reason else why  # on its own case, not the next
        state.finish(item, rec)
        if state.worker:
            rep.mcp_case = rec.to_json()  # type: ignore[attr-defined]  # for the controller's live lines
    return rep


# ---------------------------------------------------------------------- fixtures
@pytest.fixture(scope="session")
def mcp_config(pytestconfig: pytest.Config) -> RunConfig:
    """The run's parameters (``harness.config.RunConfig``)."""
    state = _state(pytestconfig)
    assert state is not None
    return state.cfg


@pytest.fixture(scope="session")
def mcp_session(pytestconfig: pytest.Config) -> Generator[Any, None, None]:
    """The node under test over the whole run; started on first use (SetupError: exit 2)."""
    state = _state(pytestconfig)
    assert state is not None
    # the node's startup is bounded by the run deadline, not by the first case's limit
    saved, state.case_deadline = state.case_deadline, None
    state.arm()
    session = state.start_session()  # never re-armed after a setup error: its alarm struck the exit
    if saved is not None:
        state.case_deadline = time.monotonic() + state.current_limit()
    state.arm()
    yield session
    state.close_session()


@pytest.fixture
def node(request: pytest.FixtureRequest, mcp_session: Any) -> Generator[Any, None, None]:
    """The per-case context: ``session.begin_case(case id, rules)``, then ``end_case``."""
    item = request.node
    state = _state(request.config)
    assert state is not None
    if item.nodeid not in state.meta:
        state.meta[item.nodeid] = _meta(item)
    rec = state.record(item)
    batch = state.batch
    ctx = batch.pending.pop(item.nodeid, None)  # made when its batch ran (conformance._batch)
    if ctx is None:
        ctx = mcp_session.begin_case(rec.id, rec.rules)
        if batch.kept is False and item.nodeid in batch.members:
            ctx.notes.append(f"ran alone after its batch was thrown away: {batch.why}")
    state.ctx[item.nodeid] = ctx
    try:
        yield ctx
    finally:
        outcome = rec.outcome
        last = state.ctx.get(item.nodeid, ctx)  # --impair: the last attempt's
        last.evidence = _log_evidence(rec)  # the capture's /log line of the case's end (issue 24)
        mcp_session.end_case(last, outcome)


# ---------------------------------------------------------------------- the end
@pytest.hookimpl(tryfirst=True)
def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    if _xdist_controller(session.config):
        merge_worker_reports(session, _state(session.config))
        return
    state = _state(session.config)
    if state is None or not state.active:
        return
    INTERRUPTS.stop_raising()  # from here on a signal only hurries: the reports get written
    if state._wait_status is not None:
        state._wait_status.close()
    state.restore_alarm()
    state.close_session()
    run = state.run
    run.finished = time.monotonic()
    if state.deadline_hit and not state.started and run.error is None:  # it struck before the startup ended
        run.error = str(state._deadline_before_startup())
    if state.deadline_hit and state.started:
        for item in state.items:
            if item.nodeid not in state.done:
                rec = state.record(item)
                rec.outcome, rec.reason = "error", "run deadline exceeded"
                state.finish(item, rec)
    if run.error is None and state.collect_errors:
        run.error = state.collect_errors[0]
    if run.error is None and INTERRUPTS.interrupted:
        run.error = INTERRUPTS.reason()
    if run.error is None and exitstatus == pytest.ExitCode.INTERRUPTED and not state.deadline_hit:
        run.error = state.interrupted or "interrupted"
    if run.error is None and exitstatus == pytest.ExitCode.INTERNAL_ERROR:
        run.error = "internal error (see the traceback above)"
    if state.list_mode and run.error is None:
        code = 0
    else:
        code = run.exit_code()
        if code == 0 and exitstatus == pytest.ExitCode.TESTS_FAILED:
            code = 1  # other (unmarked) tests of the run failed
    if state.worker:  # the controller writes the reports (conformance._run_reports)
        hand_to_controller(session, state, run)
        session.exitstatus = code
        return
    problems = write_run_reports(state, run)
    if problems:
        run.error = run.error or problems[0]
        code = 2
    if session.config.pluginmanager.get_plugin("terminalreporter") is None and not state.list_mode:
        state.terminal.summary(run)
    elif run.error is not None and (state.list_mode or state.frontend):
        state.terminal.error(run.error, run.node, run.error_detail)
    for p in problems:
        print(f"error: {p}", file=sys.stderr)
    session.exitstatus = code
    state.restore_term()


def pytest_terminal_summary(terminalreporter: Any, exitstatus: int, config: pytest.Config) -> None:
    state = _state(config)
    if state is not None and state.merged_run is not None:  # the xdist controller: once
        state.terminal.summary(state.merged_run)
        return
    if state is None or not state.active or state.list_mode:
        return
    state.terminal.summary(state.run)


def pytest_report_teststatus(report: pytest.TestReport, config: pytest.Config) -> Any:
    """A case the runner judged an error is an ERROR in pytest's summary, not FAILED."""
    if getattr(report, "mcp_outcome", None) == "error" and report.when == "call" and report.failed:
        return "error", "E", ("ERROR", {"red": True})
    return None


@pytest.hookimpl(wrapper=True)
def pytest_runtest_logreport(report: pytest.TestReport) -> Generator[None, None, None]:
    """The xdist controller prints each case's line as its worker reports it; pytest's
    --junitxml gets a case judged an error as an ``<error>`` (``conformance.junit``)."""
    result = yield
    config = getattr(report, "config", None) or _CONTROLLER.get("config") or _PLUGIN_CONFIG.get("config")
    if getattr(report, "mcp_outcome", None) == "error" and report.when == "call":
        as_pytest_error(config, report)
    case = getattr(report, "mcp_case", None)
    if case is None or report.when != "teardown":
        return result
    state = _state(config) if config is not None else None
    if state is not None and state.worker is None:
        state.terminal.case(case_from_json(case))
    return result


_CONTROLLER: dict[str, pytest.Config] = {}
_PLUGIN_CONFIG: dict[str, pytest.Config] = {}


def pytest_unconfigure(config: pytest.Config) -> None:
    if _PLUGIN_CONFIG.get("config") is config:
        _PLUGIN_CONFIG.pop("config", None)


@pytest.hookimpl(trylast=True)
def pytest_sessionstart(session: pytest.Session) -> None:
    """The xdist controller's config kept; and mcp-conform held signals through pytest's
    start-up (``conformance.cli``): from here they stop the run. Not at this plugin's own
    configure: other plugins configure after it (``_pytest.debugging`` imports pdb there), and
    a SIGTERM landing in that import became a RuntimeError in a class's ``__set_name__`` and an
    INTERNALERROR traceback (test_faults' seeded signals, 2 x SIGTERM at 0.91 s)."""
    if _xdist_controller(session.config):
        _CONTROLLER["config"] = session.config
    INTERRUPTS.release()
