"""What every case context shares, whatever the protocol and the role: the case's identity
and outcome fields, INFO notes, the generic verify and the runner's hooks
(:class:`CaseBase`); what the datagram protocol's two roles add to it, the session's
timings and the verify helpers over datagrams (:class:`DatagramCaseBase`); and what a case of
a protocol whose session carries its spec adds, the spec's parameters and a failure that
carries the node's death and the case's traffic (:class:`SpecCaseBase`, the protocol its
declared parameter: Nsqd's ``conformance._conn_case``, MAVLink's ``conformance._link_case``).

Each role's context (``conformance.drone_case.CaseContext``,
``conformance.manager_case.ManagerCaseContext`` on :class:`DatagramCaseBase`;
``conformance.nsqd_case.StreamCaseContext`` and MAVLink's on :class:`SpecCaseBase`) adds its
own sends and judgements; MCP's roles their own ``fail`` (which evidence a failure carries:
the node's exit, the manager's output).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol

from mcp_conform.harness.clock import REAL as _REAL
from mcp_conform.harness.errors import CaseFailure, Inconclusive
from mcp_conform.judge.spacing import judge_spacing
from mcp_conform.spec import SPEC

__all__ = ["CaseBase", "DatagramCaseBase", "SpecCaseBase"]


class _Described(Protocol):
    """What a verify helper's evidence is made of: a datagram, a frame."""

    def describe(self) -> str: ...


class CaseBase:
    """The fields the runner reads after a case, its hooks, and the helpers every case uses."""

    #: who is judged, in messages: "the node", "the manager"
    subject = "the node"

    def __init__(self, session: Any, case_id: str, rules: tuple[str, ...]) -> None:
        self.session = session
        self.case_id = case_id
        self.rules = rules
        clock = getattr(session, "clock", None) or _REAL  # the run's (harness.clock)
        self.start_ns = clock.time_ns()
        self.start_t = clock.monotonic()  # the same instant, on the clock of the impaired link
        self.end_ns: int | None = None
        self.notes: list[str] = []
        #: observations the case could not judge (a reply whose command is ambiguous): under
        #: ``--impair`` a passed attempt the link touched that left some is repeated too
        #: (``conformance._impaired``), as a failed one is
        self.unjudged: list[str] = []
        self.node_silent = False
        self.restart_if_failed = False
        #: what the capture's case mark carries beside the verdict (None: nothing)
        self.evidence: list[str] | None = None

    @classmethod
    def prepare_session(cls, session: Any, config: Any, items: Sequence[Any]) -> None:
        """Before the run starts: what the role's cases need of its session, from pytest's
        config and the cases collected (``items``); nothing by default."""

    @property
    def role(self) -> str:
        """The role of the node under test (``--role``, as its profile names it)."""
        return str(self.session.cfg.role)

    def conclude(self) -> None:
        """Before the case's verdict: what the role proves of the node after every case
        (a stream backend's liveness after the case's last write); nothing by default."""

    def info(self, text: str) -> None:
        """Record an observation (INFO rules; shown in every report)."""
        self.notes.append(text)

    def not_judged(self, text: str) -> None:
        """Record an observation the case could not judge (shown as a note; ``unjudged``)."""
        self.unjudged.append(text)
        self.info(text)

    def fail(self, rule: str, expected: str, actual: str, evidence: Sequence[str] = ()) -> CaseFailure:
        return CaseFailure(rule, expected, actual, list(evidence))

    def expect_true(self, ok: bool, rule: str, expected: str, actual: str, evidence: Sequence[str] = ()) -> None:
        """The generic verify for judgements over recorded observations."""
        if not ok:
            raise self.fail(rule, expected, actual, evidence)

    def expect_all(self, items: Sequence[_Described], check: Callable[[Any], str | None],
                   rule: str, expected: str, noun: str = "datagrams") -> None:
        """Every item (a datagram, a frame: anything that can ``describe()`` itself) passes
        ``check`` (which returns a problem or None); the first three that do not are the
        evidence."""
        if not items:
            raise Inconclusive(f"{rule}: {self.subject} sent nothing to judge")
        bad = [(d, p) for d in items for p in [check(d)] if p is not None]
        if bad:
            raise self.fail(rule, expected, f"{len(bad)} of {len(items)} {noun}: {bad[0][1]}",
                            [d.describe() for d, _ in bad[:3]])


class DatagramCaseBase(CaseBase):
    """What the datagram protocol's role contexts add: the session's timings and the verify
    helpers over datagrams."""

    # ------------------------------------------------------------------ facts
    @property
    def rto(self) -> float:
        return float(self.session.rto)

    @property
    def ack_window(self) -> float:
        return float(self.session.ack_window)

    @property
    def broadcast_id(self) -> int:
        return int(self.session.cfg.broadcast_id)

    # ------------------------------------------------------------------ verify helpers

    def expect_even_spacing(self, gaps: Sequence[float], rule: str = "MCP-RTX-3",
                            run_delays: Sequence[int | None] | None = None) -> None:
        """MCP-RTX-3: the gaps (s) between successive copies of one message each within
        ``rtx_spacing_tolerance`` of their median and none under ``rtx_min_gap_s``. The
        allowance is widened by the runner's own timestamp jitter (``timing_jitter_s``: it
        matters only for sub-second timeouts; at the description's 5 s it is 0.3 %). Judged
        by the monitor's own ``judge.spacing``: a gap the host's load accounts for (the
        node's run delay at each copy, ``run_delays``, where known) is excused."""
        if len(gaps) < 2:
            raise Inconclusive(f"{rule}: {len(gaps) + 1} copies are too few to judge spacing")
        sp = judge_spacing([round(g * 1e9) for g in gaps], run_delays)
        tol = float(SPEC.params["rtx_spacing_tolerance"])
        floor = float(SPEC.params["rtx_min_gap_s"])
        evidence = [f"gaps (ms): {', '.join(f'{g * 1000:.1f}' for g in gaps)}"]
        excused = (f"{sp.excused} gap(s) excused: the host kept {self.subject} off the CPU for "
                   f"{sp.starved / 1e6:.1f} ms between its copies") if sp.excused else None
        self.expect_true(not sp.bad, rule,
                         f"every gap within ±{tol:.0%} of the median gap and none under {floor * 1000:.0f} ms",
                         f"median {sp.median / 1e6:.1f} ms, outliers: {', '.join(f'{g / 1e6:.1f} ms' for g in sp.bad)}",
                         evidence + ([excused] if excused else []))
        if excused:
            self.info(f"{rule}: {excused}")


class SpecCaseBase(CaseBase):
    """A case of a protocol whose session carries its spec (``session.spec``: Nsqd's,
    MAVLink's) and names who is judged (``subject``): its parameters (``params``), the run's clock (``clock``: the host's, or the
    simulator's virtual one; ``t0``: the case's start, :meth:`now`), and a failure that says a spawned node's death
    and ends with the case's traffic (:meth:`traffic`). A protocol declares its robustness
    rule (``death_rule``: a death is reported under it, "no input ends the node", whatever
    the case tested, with the node's sanitizer line and output; "": the death is said first
    in the failure of the rule the case judged) and how long a dying node may take to be seen
    dead (:meth:`death_grace`)."""

    death_rule = ""

    def __init__(self, session: Any, case_id: str, rules: tuple[str, ...]) -> None:
        super().__init__(session, case_id, rules)
        self.subject = getattr(session, "subject", self.subject)  # who is judged: its session's
        self.spec = session.spec
        self.params = self.spec.params
        self.clock = getattr(session, "clock", None) or _REAL  # as CaseBase takes it
        self.t0 = self.clock.monotonic()

    def now(self) -> float:
        """The run clock's ``monotonic()``: the time of a send, of a frame's arrival."""
        return float(self.clock.monotonic())

    def traffic(self) -> list[str]:
        """The case's traffic, the last of a failure's evidence."""
        return []

    def death_grace(self) -> float:
        """How long a failure waits for the spawned node's death (a sanitizer takes a moment)."""
        return 0.05

    def fail(self, rule: str, expected: str, actual: str, evidence: Sequence[str] = ()) -> CaseFailure:
        """The failure to raise: the rule's, a spawned node that died said first; or, under
        :attr:`death_rule`, the death (one fault, one root: the evidence names the case's
        rules and what it sent)."""
        death = self.session.death(grace=self.death_grace())
        if death is None or not self.death_rule:
            return CaseFailure(rule, expected, actual, ([death.describe()] if death is not None else [])
                               + list(evidence) + self.traffic())
        ev = ([death.sanitizer] if death.sanitizer else []) + self.traffic() + [f"stderr: {line}" for line in death.stderr[-6:]]
        ev.append(f"while testing {', '.join(self.rules)} ({self.case_id})")
        return CaseFailure(self.death_rule, f"{self.subject} survives the input and keeps serving",
                           death.describe(), ev, relies_on=())
