"""The runner's state over one pytest run (``McpState``, kept in ``config.stash`` under
``STATE_KEY``): the run's configuration, its records (cases, outcomes, reports), the session
under test, time limits and signals (the report files are ``conformance._run_reports``'). The hooks that drive it
are ``conformance._plugin_run``'s; this module holds no hook."""

from __future__ import annotations

import atexit
import contextlib
import os
import signal
import tempfile
import threading
import time
from collections.abc import Iterator
from typing import Any, NoReturn

import pytest
from rich.console import Console

from mcp_conform.conformance.baseline import Baseline
from mcp_conform.conformance.marks import (
    case_id,
    case_phase,
    case_rules,
    strongest_level,
)
from mcp_conform.conformance.options import (
    apply_embedded_defaults,
)
from mcp_conform.conformance.report import CaseRecord, RunRecord, name_consequence
from mcp_conform.conformance.terminal import TerminalReport
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.errors import SetupError, SpawnFailure
from mcp_conform.harness.interrupts import INTERRUPTS
from mcp_conform.harness.node import check_node
from mcp_conform.spec.profiles import resolve

__all__ = ["STATE_KEY", "CaseTimeLimit", "McpState", "state_of"]


class CaseTimeLimit(Exception):
    """Raised by the SIGALRM handler: the case (or the run) ran out of time."""


STATE_KEY = pytest.StashKey["McpState"]()


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__


def state_of(config: pytest.Config) -> McpState | None:
    return config.stash.get(STATE_KEY, None)



# ---------------------------------------------------------------------- run state
class McpState:
    """Everything the plugin keeps for one pytest run."""

    def __init__(self, config: pytest.Config, cfg: RunConfig, frontend: bool) -> None:
        self.config = config
        self.cfg = cfg
        self.frontend = frontend
        self.active = False
        self.list_mode = bool(config.getoption("mcp_list"))
        self.select: list[str] = list(config.getoption("mcp_select") or [])
        self.exclude: list[str] = []
        self.user_timeouts: dict[str, float] = {}  # nodeid -> pytest-timeout's --timeout
        self.case_user_timeout: float | None = None  # of the case in progress
        self.case_limit_text = ""
        self.baseline: Baseline | None = None
        self.junit_family = "xunit2"
        self.write_baseline_path: str | None = None
        self.worker: str | None = None  # the pytest-xdist worker id, on a worker
        self.worker_docs: list[dict[str, Any]] = []  # on the xdist controller
        self.capture_parts: list[str] = []
        self.merged_run: RunRecord | None = None
        self.run = RunRecord(role=cfg.role, target=self._target_guess(), parameters=cfg.parameters(),
                             seed=cfg.seed, strict=cfg.strict)
        self.session: Any = None
        self.recorder: Any = None
        self.live: Any = None  # traceio.live.LiveServer under --live
        self.html_path: str | None = None
        self.html_capture: str | None = None  # the run's recording for --mcp-html without --mcp-capture
        self.items: list[pytest.Item] = []
        self.meta: dict[str, tuple[str, tuple[str, ...], str, str]] = {}  # nodeid -> id, rules, level, phase
        self.records: dict[str, CaseRecord] = {}
        self.done: set[str] = set()
        self.ctx: dict[str, Any] = {}
        self.collect_errors: list[str] = []
        self.run_deadline: float | None = None
        self.case_deadline: float | None = None
        self.grace_deadline: float | None = None  # a case's teardown: at least this long
        self.grace_s = 0.0
        self.deadline_hit = False
        # the node's startup ended (its session.start() returned): from here the run's deadline
        # ends the cases not run; before, it is a setup error and the report holds no case
        self.started = False
        self._alarm_held = False  # the run's SIGALRM waits for alarm_held()'s block to end
        self._alarm_pending = False
        self.interrupted: str | None = None
        self._old_alarm: Any = None
        self._old_term: Any = None
        self._terminal: TerminalReport | None = None
        self._wait_status: Any = None
        self.first_datagram: Any = None  # conformance.run_display.FirstDatagram, during the run
        self.printer: Any = None  # conformance.run_display.TrafficPrinter under -v
        self.startup_deadline: float | None = None  # until the node's first datagram
        self.plan: Any = None  # conformance.schedule.Plan, once the cases are collected
        self.batch_items: list[pytest.Item] = []  # the plan's batch, in its order
        self.serial_order: list[pytest.Item] = []  # the items as --serial runs them
        from mcp_conform.conformance._batch import BatchRun

        self.batch = BatchRun()
        self.startup_expired = False
        self.shard: tuple[int, int] | None = None  # (K, N): mcp-conform --parallel's instance K of N
        self.events_path: str | None = None  # where that instance tells the front end its progress
        # the observed startup phase's parts this instance observes (a shard: the plan's, none
        # is the quick startup; None: all of them, a run of one)
        self.startup_parts: frozenset[str] | None = None

    @property
    def startup_timeout(self) -> float:
        """--startup-timeout, never beyond the run's --timeout."""
        return min(float(self.cfg.extra.get("startup_timeout", self.cfg.timeout)), self.cfg.timeout)

    def _target_guess(self) -> str | None:
        if self.cfg.target is not None:
            return f"{self.cfg.target[0]}:{self.cfg.target[1]}"
        return None

    @property
    def terminal(self) -> TerminalReport:
        if self._terminal is None:
            tr = self.config.pluginmanager.get_plugin("terminalreporter")
            before = None
            if tr is not None:
                def before() -> None:  # end pytest's progress line before ours
                    tw = getattr(tr, "_tw", None)
                    if tw is not None and getattr(tw, "width_of_current_line", False):
                        tw.line()
            self._terminal = TerminalReport(Console(highlight=False), before_line=before)
            if self.events_path:  # the run's notes reach the front end of --parallel too
                note = self._terminal.note

                def told(text: str) -> None:
                    note(text)
                    self.emit({"note": text})
                self._terminal.note = told  # type: ignore[method-assign]
        return self._terminal

    # ------------------------------------------------------------------ session
    def start_session(self) -> Any:
        if self.session is not None:
            return self.session
        if self.run.error is not None:
            pytest.exit(self.run.error, returncode=2)
        try:
            apply_embedded_defaults(self.cfg)
            self.run.parameters = self.cfg.parameters()
            if self.html_path and not self.cfg.capture:  # the HTML report's charts need the traffic
                fd, self.html_capture = tempfile.mkstemp(prefix="mcp-conform-", suffix=".mcap")
                os.close(fd)
            feed = self.start_live()
            if self.cfg.capture or self.html_capture or feed is not None:
                from mcp_conform.traceio.recorder import McapRecorder, RecorderError, run_metadata

                cfg = self.cfg
                meta = run_metadata("mcp-conform", mode=cfg.mode, role=cfg.role, seed=cfg.seed,
                                    target=f"{cfg.target[0]}:{cfg.target[1]}" if cfg.target else None,
                                    spawn=cfg.spawn, parameters=self.run.parameters)
                try:  # never a file cut off after its header (a signal, the run's deadline)
                    with INTERRUPTS.held(), self.alarm_held():
                        # --live without a file: a recorder of no file feeds the live server
                        self.recorder = McapRecorder(self.cfg.capture or self.html_capture, metadata=meta,
                                                     live=feed)
                except RecorderError as exc:
                    raise SetupError(str(exc)) from None
            recorder = self.recorder
            from mcp_conform.conformance.run_display import (
                FirstDatagram,
                Tee,
                TrafficPrinter,
                listen_text,
            )

            printer = None
            if self.config.getoption("mcp_verbose_traffic"):
                capman = self.config.pluginmanager.getplugin("capturemanager")
                printer = self.printer = TrafficPrinter(
                    uncaptured=capman.global_and_fixture_disabled if capman is not None else None)
            # a datagram node's first datagram ends the --startup-timeout wait (a stream
            # node's startup is its connection, bounded by the session itself)
            awaited = resolve(self.cfg.profile()[1].session).first_awaited
            self.first_datagram = FirstDatagram(awaited) if awaited is not None else None
            if printer is not None or self.first_datagram is not None:
                recorder = Tee(self.recorder, printer, self.first_datagram)
            session = check_node(self.config.hook.pytest_mcp_make_session(cfg=self.cfg, recorder=recorder,
                                                                          config=self.config))
            self.session = session
            self.run.parameters = self.cfg.parameters()  # as the session settled them (mavlink ...)
            resume = self.wait_status.current
            if self.frontend and session.startup_note is not None:
                line, status = session.startup_note  # the role's own startup (--role manager, a backend)
                self.terminal.note(line)
                self.wait_status.begin(status)
            elif self.frontend:
                self.terminal.note(f"startup phase: the node starts, announces Mission_Ready and "
                                   f"retransmits it while the runner withholds the ACK (--rto {self.cfg.rto:g} s)")
            watch = self.first_datagram
            if watch is not None and self.frontend:
                self.wait_status.begin(watch.waiting_text, total=self.startup_timeout, plain=True,
                                       until=watch.seen,
                                       then="startup phase: watching Mission_Ready and its retransmissions")
            atexit.register(self.close_session)
            # the startup phase is bounded by its own waits and the run deadline, not by the
            # time limit of the case that happens to start it; the wait for the node's first
            # datagram by --startup-timeout
            self.case_deadline = None
            if watch is not None:
                self.startup_deadline = time.monotonic() + self.startup_timeout
            self.arm()
            try:
                if self.startup_parts is None:
                    session.start()
                else:  # a shard: its parts of the observed startup (none: the quick one), still diagnosed
                    session.start(diagnose=True, parts=self.startup_parts)
            except CaseTimeLimit:
                # the run's deadline (or --startup-timeout) fell in the startup phase: the node
                # never became ready
                self.deadline_hit = False
                if self.startup_expired:
                    why = (f"--startup-timeout: no datagram from the node within {self.startup_timeout:g} s "
                           f"({watch.awaited() if watch else 'none'} to "
                           f"{listen_text(watch.local if watch else None)})")
                    raise session.startup_unanswered(why) from None  # with what it saw
                raise session.startup_timed_out(self.cfg.timeout) from None
            finally:
                self.startup_deadline = None
                self.wait_status.end()
                if resume:
                    self.wait_status.begin(resume)  # the first case, which started the node
            self.started = True
            self.case_deadline = time.monotonic() + self.current_limit()
            self.arm()
        except (SetupError, CaseTimeLimit) as caught:
            if self.started:  # the deadline once the node is up: the cases not run end
                raise
            self.fail_setup(caught)
        self.run.target = session.target_desc or self.run.target
        unreadable = session.unreadable
        if unreadable is not None:
            self.terminal.note(f"startup phase: {unreadable[1]} ({unreadable[0]}): no mission is started; "
                               "only the cases judged on the datagrams' raw bytes are run, the others "
                               "are skipped")
        timing = session.timing
        if timing is not None:
            self.terminal.note(timing)
            self.run.parameters["timing"] = timing
        watch = session.liveness.loss_after if session.liveness is not None else None
        if watch is not None:
            self.run.parameters["loss_after_s"] = watch
            self.terminal.note(f"liveness: the node is declared lost after {watch:g} s without an "
                               "answer to the runner's probes" + (" (its process is watched too)"
                                                                  if self.cfg.spawn else ""))
        return session

    def start_live(self) -> Any:
        """``--live [HOST:]PORT`` (issue 24): the Foxglove WebSocket server of the run, its URL
        printed; the feed the run's recorder writes to (None without --live). A port in use is
        a one-line SetupError."""
        value = self.config.getoption("mcp_live", None)
        if not value or self.live is not None:
            return None if self.live is None else self.live.feed()
        from mcp_conform.traceio.live import LAYOUT_PATH, LiveError, LiveServer, parse_live

        try:
            host, port = parse_live(value, "--live" if self.frontend else "--mcp-live")
            self.live = LiveServer(host, port, name="mcp-conform")
        except LiveError as exc:
            raise SetupError(str(exc)) from None
        self.terminal.note(f"live: {self.live.url} (Foxglove: Open connection, Foxglove WebSocket; "
                           f"layout: {LAYOUT_PATH})")
        return self.live.feed()

    def close_session(self) -> None:
        atexit.unregister(self.close_session)  # closed: an in-process run (the simulator's) is released
        session, self.session = self.session, None
        if session is not None:
            with contextlib.suppress(Exception):
                session.close()
            monitor = session.monitor  # the report's monitor section
            if monitor is not None:
                with contextlib.suppress(Exception):
                    monitor.finish()
                    self.run.monitor = monitor.to_json()
        recorder, self.recorder = self.recorder, None
        if recorder is not None:
            with contextlib.suppress(Exception):
                recorder.close()
        live, self.live = self.live, None
        if live is not None:  # nothing left listening once the run is over
            with contextlib.suppress(Exception):
                live.stop()
        if self.printer is not None:  # -v: the lines still held, before the summary
            with contextlib.suppress(Exception):
                self.printer.close()

    # ------------------------------------------------------------------ records
    def record(self, item: pytest.Item) -> CaseRecord:
        rec = self.records.get(item.nodeid)
        if rec is None:
            cid, ids, level, _ = self.meta.get(item.nodeid) or _meta(item)
            rec = self.records[item.nodeid] = CaseRecord(id=cid, rules=ids, level=level)
            rec.duration_s = 0.0
        return rec

    @property
    def wait_status(self) -> Any:
        """The progress line (frontend on a terminal only; pytest shows its own progress)."""
        if self._wait_status is None:
            from mcp_conform.conformance.run_display import WaitStatus

            self._wait_status = WaitStatus(self.terminal.console)
            self._wait_status.enabled = self._wait_status.enabled and self.frontend
        return self._wait_status

    def finish(self, item: pytest.Item, rec: CaseRecord) -> None:
        if item.nodeid in self.done:
            return
        self.wait_status.end()
        self.done.add(item.nodeid)
        ctx = self.ctx.pop(item.nodeid, None)
        if self.ended_in_setup():  # a case the run's setup error cut short never ran: no record
            return
        if ctx is not None:
            rec.notes = list(ctx.notes)
            rec.start_ns, rec.end_ns = ctx.start_ns, ctx.end_ns
            if rec.start_ns is not None and rec.end_ns is not None:
                rec.duration_s = max(0.0, (rec.end_ns - rec.start_ns) / 1e9)
        if rec.notes and rec.actual is None and rec.outcome in ("passed", "info"):
            rec.actual = "; ".join(rec.notes)
        name_consequence(rec, self.run.cases)
        self.run.cases.append(rec)
        self.terminal.case(rec)
        self.emit({"case": rec.to_json()})

    # ------------------------------------------------------------------ shards (--parallel)
    def set_shard(self, value: str | None, events: str | None) -> None:
        """``--mcp-shard K/N`` (``mcp-conform --parallel``): run instance K's share of the plan
        shared out across N; ``events``: the file its progress is appended to."""
        self.events_path = events
        if not value:
            return
        k, sep, n = value.partition("/")
        if not sep or not k.isdigit() or not n.isdigit() or not 0 <= int(k) < int(n):
            raise ValueError(f"{value!r} is not K/N with 0 <= K < N")
        if self.cfg.mode == "attach":
            raise ValueError("attach mode has one node under test: it cannot be shared out")
        self.shard = (int(k), int(n))

    def take_shard(self, items: list[pytest.Item]) -> None:
        """Keep this instance's cases of the plan (``conformance.schedule.shard_plan``), in
        its order; the plan (every instance's) is the report's and the front end's."""
        from mcp_conform.conformance.schedule import shard_plan

        assert self.shard is not None and self.plan is not None
        k, n = self.shard
        apply_embedded_defaults(self.cfg)  # the estimates' timings: the run's
        plan = self.plan = shard_plan(self.plan, n, self.cfg.rto, self.cfg.ack_window)
        self.run.schedule = plan.to_json()
        mine = set(plan.of_shard(k)) if k < plan.shards else set()
        drop = [i for i in items if i.nodeid in self.meta and self.meta[i.nodeid][0] not in mine]
        if drop:
            gone = set(drop)
            items[:] = [i for i in items if i not in gone]
            self.config.hook.pytest_deselected(items=drop)
            self.batch_items = [i for i in self.batch_items if i not in gone]
            self.serial_order = [i for i in self.serial_order if i not in gone]
        self.startup_parts = plan.startup_parts(k)
        self.emit({"plan": plan.to_json()})

    def emit(self, event: dict[str, Any]) -> None:
        """One line of this instance's progress for the front end (``--mcp-shard-events``)."""
        if not self.events_path:
            return
        import json

        with open(self.events_path, "a", encoding="utf-8") as f:
            f.write(json.dumps(event) + "\n")

    def fail_setup(self, caught: BaseException) -> NoReturn:
        """End the run with a setup error (exit 2, its one line): ``caught`` a ``SetupError``, or
        the run's deadline (``CaseTimeLimit``) before the node's startup ended, wherever it struck
        (the first case's setup, the session's making, the startup; a SetupError it cut short is
        the one said). The first error stands; the report holds no case (``ended_in_setup``)."""
        self.disarm()
        err = caught
        if not isinstance(err, SetupError):
            err = caught.__context__ if isinstance(caught.__context__, SetupError) else self._deadline_before_startup()
        if self.run.error is None:
            self.run.error = str(err).strip().splitlines()[0] if str(err).strip() else "setup error"
            self.run.node = err.node if isinstance(err, SpawnFailure) else None
            self.run.error_detail = list(getattr(err, "detail", ()))
        self.close_session()
        pytest.exit(self.run.error, returncode=2)

    def ended_in_setup(self) -> bool:
        """The run ends in a setup error: its node's startup never ended and the run has an
        error or its deadline passed. Its cases never ran, so none is recorded (docs/design.md,
        exit code 2: a setup error is its one line), wherever the deadline's SIGALRM struck."""
        return not self.started and (self.run.error is not None or self.deadline_hit)

    def _deadline_before_startup(self) -> Exception:
        """The error of a time limit that fell while the runner made its session, before the
        node's startup began (its recorder, its sockets, the modules it imports: on a loaded
        host the run's 3-s --timeout passed there, and each of the 44 cases was an error, "run
        deadline exceeded", CI run 50): a setup error as one in the startup is, never case errors."""
        self.deadline_hit = False
        if self.session is not None:
            return self.session.startup_timed_out(self.cfg.timeout)
        return SetupError(f"the run's --timeout of {self.cfg.timeout:g} s passed before the runner reached the "
                          "target (its own start-up took all of it)")

    # ------------------------------------------------------------------ time limits
    def current_limit(self) -> float:
        """The case in progress's time limit: the runner's own, or the user's pytest-timeout
        ``--timeout`` where that is shorter (and says so when it strikes)."""
        limit = self.cfg.per_case_limit()
        self.case_limit_text = f"its time limit of {limit:g} s"
        user = self.case_user_timeout
        if user is not None and user < limit:
            limit, self.case_limit_text = user, f"the --timeout of {user:g} s (pytest-timeout)"
        return limit

    def arm(self) -> None:
        """Arm SIGALRM for the rest of the case (or the run, whichever ends first); in a
        case's teardown (``arm_teardown``) never before its grace period is over."""
        if not _can_alarm():
            return
        now = time.monotonic()
        ends = [d for d in (self.case_deadline, self.run_deadline, self.startup_deadline) if d is not None]
        if not ends:
            signal.setitimer(signal.ITIMER_REAL, 0)
            return
        if self._old_alarm is None:
            self._old_alarm = signal.signal(signal.SIGALRM, self._on_alarm)
        end = min(ends) if self.grace_deadline is None else max(min(ends), self.grace_deadline)
        signal.setitimer(signal.ITIMER_REAL, max(end - now, 0.001))

    def arm_teardown(self, grace_s: float) -> None:
        """A case's teardown (its node fixture ends the case) is bounded by the rest of the
        case's limit, but it is given at least ``grace_s`` of its own: a case that ran out of
        time (in its setup or its call) is still torn down, so the next case starts clean (a
        limit already past cut pytest's own teardown short: the NEXT case errored, "previous
        item was not torn down properly"). An overrun is the torn-down case's error."""
        self.grace_s, self.grace_deadline = grace_s, time.monotonic() + grace_s
        self.arm()

    def disarm(self) -> None:
        if not _can_alarm():
            return
        signal.setitimer(signal.ITIMER_REAL, 0)

    def restore_alarm(self) -> None:
        if _can_alarm() and self._old_alarm is not None:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, self._old_alarm)
            self._old_alarm = None

    @contextlib.contextmanager
    def alarm_held(self) -> Iterator[None]:
        """Within: the run's SIGALRM waits for the block to end (the capture's recorder is made
        whole, never left without its footer), then strikes; not after an exception."""
        saved, self._alarm_held = self._alarm_held, True
        try:
            yield
        except BaseException:
            self._alarm_held, self._alarm_pending = saved, saved and self._alarm_pending
            raise
        self._alarm_held = saved
        if not saved and self._alarm_pending:
            self._alarm_pending = False
            self._on_alarm(signal.SIGALRM, None)

    def _on_alarm(self, signum: int, frame: Any) -> None:
        if self._alarm_held:
            self._alarm_pending = True
            return
        now = time.monotonic()
        if self.startup_deadline is not None and now >= self.startup_deadline - 0.002 and not (
                self.run_deadline is not None and now >= self.run_deadline - 0.002):
            watch = self.first_datagram
            self.startup_deadline = None
            if watch is not None and watch.seen.is_set():  # the node spoke: the startup goes on
                self.arm()
                return
            self.startup_expired = True
            raise CaseTimeLimit("startup timeout")
        if self.run_deadline is not None and now >= self.run_deadline - 0.002:
            self.deadline_hit = True
            if self.grace_deadline is None or now < self.grace_deadline - 0.002:
                raise CaseTimeLimit("run deadline exceeded")
        if self.grace_deadline is not None and now >= self.grace_deadline - 0.002:
            raise CaseTimeLimit(f"teardown overran its grace of {self.grace_s:g} s")
        raise CaseTimeLimit(f"case exceeded {self.case_limit_text}")

    def install_term(self) -> None:
        """SIGINT / SIGTERM (``harness.interrupts``): the first stops the run, later
        ones hurry it; none can skip the reports. Installed here when plain pytest runs us
        (``mcp-conform`` installs it before anything else)."""
        self._old_term = INTERRUPTS.install()

    def restore_term(self) -> None:
        if self._old_term:
            INTERRUPTS.restore()
            self._old_term = None


def _can_alarm() -> bool:
    return hasattr(signal, "setitimer") and threading.current_thread() is threading.main_thread()


def _meta(item: pytest.Item) -> tuple[str, tuple[str, ...], str, str]:
    ids = case_rules(item)
    return case_id(item), ids, strongest_level(ids), case_phase(item)

