"""From a flaw seen in a campaign to a finding: group, confirm, shrink, keep.

A flaw whose (rule, shape) group already has a confirmed finding is only counted. Otherwise
the datagrams that led to it are replayed (``fuzz.replay``) on a fresh node when spawned, on
the same node when attached, once its liveness probe is ACKed (a node lost in attach mode
ends the campaign: ``TargetLost``, issue 19 item 1): not reproduced, it is dropped (counted as unconfirmed in the
summary, never reported); reproduced, it is shrunk to the minimal sequence that still shows
the same rule (every protocol's one search, ``fuzz.triage_core.search``: the suspects alone,
then every input before it delta debugged), and that sequence must show it again in each of ``CONFIRM_N`` more replays
(N of N) before it is kept.

Blame (issue 36 item 2): a flaw is tied to its input only when the input makes the
difference. Before its input is replayed, the same observation without it -- a fresh node sent
a valid WP_Off in the input's place (then the liveness probe, as after every input) -- is run once per worker and
confirmed ``CONFIRM_N`` times: a rule it breaks is the node's behaviour whatever it is sent,
kept as one finding (shape :data:`NO_INPUT`, its one datagram that valid message), and every flaw of that rule
is counted there, no input blamed.

State (issue 36 item 3): a frame delivered to the autopilot more often than the duplicate
rules allow (MCP-DUP-1, seen on the vehicle link) is a copy of a message the node delivered
before; the copy alone on a fresh node is no duplicate, so it is replayed after its original
(the datagram twice: the node's state before the input). Replayed, the copy waits for its
original's forwards to settle: a copy that added no delivery is not MCP-DUP-1's, and a frame
already over-delivered before it is the original's (MCP-PAY-8: a node that forwards each
frame twice), the finding named by that rule (``Triage._copy_or_original``). Likewise a missing ACK (MCP-ACK-1) is
tried after the earlier inputs of its (src, seq) before every input is delta debugged: a node
that takes a message for a copy by its (src, seq) leaves it unACKed. A flaw that reproduced at least once
but not every time depends on the environment (timing, load): it is not a finding, but it is
named in the summary (``environment_dependent``) with why, not lost among the unconfirmed.

Budget: no replay starts after the campaign's deadline (``started`` + ``duration``:
``fuzz.budget.check_late``), so ``--duration``
bounds triage too, within ``fuzz.budget.GRACE_S``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import replace

from mcp_conform.fuzz.findings import NO_INPUT, Finding, FindingStore
from mcp_conform.fuzz.loop import triage_time
from mcp_conform.fuzz.oracles import OVERSIZE, Flaw, Input
from mcp_conform.fuzz.replay import Outcome, run_sequence
from mcp_conform.fuzz.target_base import TargetBase
from mcp_conform.fuzz.triage_core import HitTriage, search
from mcp_conform.spec.codec import HEADER_SIZE, Action, build_datagram

__all__ = ["Triage", "shape_of"]

_DEATH = ("liveness", "process")  # flaws of a node that died or hung: one family
MAX_GROUPS = 32  # a node broken everywhere: stop confirming new groups after this many
SHRINK_BUDGET = 24  # replays per finding
SUSPECTS = 6  # single inputs tried alone before delta debugging
CONFIRM_N = 3  # replays of the minimal sequence, all of which must show the flaw
BASELINE_SRC = 0x0B5E  # the baseline's valid case comes from this source ID


def _size_class(n: int) -> str:
    return "short" if n < HEADER_SIZE else ("oversized" if n > OVERSIZE else "sized")


def shape_of(flaw: Flaw, inputs: Sequence[Input]) -> str:
    """What kind of input and what kind of answer: the grouping key beside the rule."""
    if flaw.source in _DEATH:
        last = _size_class(len(inputs[-1].data)) if inputs else "no input"
        return f"{flaw.source}: {flaw.actual.split(' after ')[0]}, {last}"
    if flaw.culprit is not None and 0 <= flaw.culprit < len(inputs):
        inp = inputs[flaw.culprit]
        if inp.msg is not None:
            # the rule says what was wrong with ACKing it (broadcast, other ID, an ACK);
            # for a missing ACK the action code is the shape
            what = f"valid {Action(inp.msg.action).name}" if flaw.rule == "MCP-ACK-1" else "valid message"
        else:
            assert inp.error is not None
            what = f"rejected {inp.error.rule} {_size_class(len(inp.data))}"
    else:
        what = "sequence"
    return f"{flaw.source}: {what}"


class Triage(HitTriage):
    """Turns flaws into findings for one worker's target (its steps and counts:
    ``fuzz.triage_core.HitTriage``)."""

    def __init__(self, target: TargetBase, store: FindingStore, engine: str, seed: int,
                 worker: int = 0) -> None:
        self.engine = engine
        super().__init__(target=target, store=store, seed=seed, worker=worker, n_of_n=CONFIRM_N)
        # a death is blamed on its input only once shrinking found it: (rule, shape) as first
        # seen -> the group it ended in
        self.aliases: dict[tuple[str, str], tuple[str, str]] = {}
        self.baseline_rules: set[str] | None = None  # rules the node breaks sent no input (once run)

    def consider(self, flaw: Flaw, inputs: Sequence[Input], pace: str,
                 program: str | None = None, scenario: str | None = None) -> Finding | None:
        """Handle one flaw seen after ``inputs``; the new finding, if one was kept."""
        if flaw.source in _DEATH:
            # attach mode: a node that is dead now is lost, not a finding (TargetLost)
            self.target.check_live("after the inputs that preceded it")
        shape = shape_of(flaw, inputs)
        key = self.aliases.get((flaw.rule, shape), (flaw.rule, shape))
        if self.store.known(*key):
            self.store.count(*key)
            return None
        if len(self.store) >= MAX_GROUPS:
            return None
        with triage_time(self, flaw.rule):
            if scenario is None and flaw.source not in _DEATH and self._baseline(flaw, pace):
                return None
            return self._confirm_and_shrink(flaw, inputs, shape, pace, program, scenario)
        return None  # past the deadline (Late): counted untriaged

    def _run(self, seq: list[bytes], pace: str, scenario: str | None):  # noqa: ANN202
        """One replay (``run_sequence``); none once the deadline passed (``Late``)."""
        # MCP's triage is bounded by the deadline alone
        return self.replay(lambda: run_sequence(self.target, seq, pace=pace, scenario=scenario), share=False)

    def _baseline(self, flaw: Flaw, pace: str) -> bool:
        """Whether ``flaw``'s rule is the node's behaviour whatever it is sent: its liveness
        probe alone on a fresh node breaks it ``CONFIRM_N`` times of as many (run once per
        worker; its finding kept with no datagram). True: counted there, no input blamed."""
        if self.baseline_rules is None:
            first_input = self._valid()
            first = self._run([first_input], pace, None)
            rules = first.rules()
            seen = {r: next(f for f in first.flaws if f.rule == r) for r in rules}
            for _ in range(CONFIRM_N - 1):
                if not rules:
                    break
                rules &= self._run([self._valid()], pace, None).rules()
            self.baseline_rules = rules
            for r in sorted(rules):
                if self.store.known(r, NO_INPUT):
                    continue
                traffic = [(t.direction, t.t_ns, t.data, t.addr) for t in first.traffic]
                self.store.add(Finding.from_flaw(seen[r], [first_input], NO_INPUT, self.engine, self.seed, pace,
                                                 worker=self.worker, target=self._target_doc()), traffic)
        if flaw.rule in self.baseline_rules:
            self.store.count(flaw.rule, NO_INPUT)
            return True
        return False

    def _valid(self) -> bytes:
        """The valid case put in an input's place: a WP_Off unicast to the node (the probe's
        kind of message), from a source of its own (no seq of the campaign's reused)."""
        return build_datagram(self.target.node_id, BASELINE_SRC, int(time.monotonic() * 1000) & 0xFFFF, Action.WP_OFF)

    def _target_doc(self) -> dict[str, object]:
        return {"mode": self.target.cfg.mode, "spawn": self.target.run_cfg.spawn, "mavlink": self.target.cfg.mavlink,
                "role": self.target.cfg.role}

    def _still(self, flaw: Flaw, pace: str, scenario: str | None) -> Callable[[list[bytes]], bool]:
        """The search's predicate (``fuzz.triage_core.HitTriage.shows``): a sequence replayed
        (``run_sequence``) still shows the flaw: its rule, or a death of any cause for a death."""
        def replay(seq: list[bytes]) -> Flaw | None:
            out = run_sequence(self.target, seq, pace=pace, scenario=scenario)
            death = flaw.source in _DEATH
            return next((f for f in out.flaws if (f.source in _DEATH if death else f.rule == flaw.rule)), None)
        return self.shows(replay, share=False)  # MCP's triage is bounded by the deadline alone

    def _copy_or_original(self, flaw: Flaw, seqs: list[list[bytes]], pace: str, scenario: str | None) -> Flaw:
        """A frame over-delivered after a copy of its message (MCP-DUP-1 as the campaign saw
        it: the copy sent right behind its original) is the copy's only if the copy added a
        delivery. Replayed, the copy waits for its original's forwards to settle
        (``fuzz.replay.settled_count``) and the ledger blames it only when the frame's count
        grew after it; a count already over before it is the original's (MCP-PAY-8: a node
        that forwards each frame twice, which breaks no duplicate rule). The first of ``seqs``
        (the original then its copy, then the inputs up to the flaw) whose replay shows the
        frame over-delivered decides the rule the search and the confirmation look for."""
        for seq in seqs:
            out = self._run(seq, pace, scenario)
            f = next((f for f in out.flaws if f.source == "vehicle" and f.datagram == flaw.datagram
                      and f.rule in ("MCP-DUP-1", "MCP-PAY-8")), None)
            if f is not None:
                return flaw if f.rule == flaw.rule else replace(flaw, rule=f.rule, evidence=f.evidence)
        return flaw

    @staticmethod
    def _suspects(flaw: Flaw, inputs: Sequence[Input]) -> list[bytes]:
        """Single inputs worth replaying alone first: the culprit, and for a death the short
        and oversized inputs (the usual killers), last ones first."""
        out = []
        if flaw.culprit is not None and flaw.source not in _DEATH:
            out.append(inputs[flaw.culprit].data)
        if flaw.source == "vehicle" and flaw.culprit is not None:
            # delivered too often: a copy of a message delivered before (the node's state
            # before the input: the original, then the copy)
            out.append(inputs[flaw.culprit].data)
        if flaw.source in _DEATH:
            for inp in reversed(inputs):
                if _size_class(len(inp.data)) != "sized" and inp.data not in out:
                    out.append(inp.data)
            if inputs and inputs[-1].data not in out:
                out.append(inputs[-1].data)
        return out[:SUSPECTS]

    @staticmethod
    def _same_seq(flaw: Flaw, inputs: Sequence[Input]) -> list[bytes]:
        """A missing ACK's likeliest state (MCP-ACK-1 "every copy", MCP-DUP-*): the inputs
        before the culprit with its source and seq, then the culprit -- a node that takes a
        message for a copy of an earlier one by its (src, seq) may leave it unACKed. [] when
        the flaw is no missing ACK or no earlier input has that (src, seq)."""
        if flaw.rule != "MCP-ACK-1" or flaw.source != "replies" or flaw.culprit is None \
                or not 0 <= flaw.culprit < len(inputs):
            return []
        culprit = inputs[flaw.culprit]
        if culprit.header is None:
            return []
        src, seq = culprit.header[1:3]
        same = [i.data for i in inputs[:flaw.culprit] if i.header is not None and i.header[1:3] == (src, seq)]
        return [*same, culprit.data] if same else []

    def _confirm_and_shrink(self, flaw: Flaw, inputs: Sequence[Input], shape: str, pace: str,
                            program: str | None, scenario: str | None) -> Finding | None:
        end = flaw.culprit + 1 if flaw.culprit is not None and flaw.source not in _DEATH else len(inputs)
        candidate = [i.data for i in inputs[:end]]
        # the one search (fuzz.triage_core.search): a scenario alone, the suspects alone (a copy
        # after its original; a missing ACK after the inputs of its (src, seq)), then every
        # input before it together, delta debugged (its budget spent, a 64-input batch's
        # missing ACK was left at 4 datagrams after 29 replays, each that showed it paying
        # MCP-ACK-1's observation: 5 copies, the last watched --ack-window)
        s = self._suspects(flaw, inputs)
        if flaw.rule == "MCP-DUP-1" and flaw.source == "vehicle" and s:
            blamed = self._copy_or_original(flaw, [[s[0]] * 2, candidate], pace, scenario)
            if blamed.rule != flaw.rule:  # the original's: later such flaws are counted there
                self.aliases[(flaw.rule, shape)] = (blamed.rule, shape)
                if self.store.known(blamed.rule, shape):
                    self.store.count(blamed.rule, shape)
                    return None
                flaw = blamed
        same_seq = self._same_seq(flaw, inputs)
        tries: list[list[bytes]] = ([[]] if scenario is not None else []) + [[d] for d in s[:1]] \
            + ([[s[0]] * 2] if flaw.source == "vehicle" and s else []) + ([same_seq] if same_seq else []) \
            + [[d] for d in s[1:]]
        found = search(candidate, self._still(flaw, pace, scenario), tries=tries, budget=SHRINK_BUDGET,
                       singles=min(SHRINK_BUDGET // 2, 8))
        if found is None:
            self.count_unconfirmed(flaw.rule)
            return None
        minimal: list[bytes] = found
        # the minimal sequence CONFIRM_N times more, each on a fresh node when spawned, at the
        # campaign's pace: every one shows the flaw, or there is no finding (issue 18 item 9:
        # findings confirmed once in two tries replayed 0 of 3 afterwards); the first
        # replay's answers are what the finding records
        missed: dict[str, set[str]] = {}
        seq: list[bytes] = minimal

        def once(log: list[object]) -> tuple[Flaw, Outcome] | None:
            out = run_sequence(self.target, seq, pace=pace, scenario=scenario)
            again = next((f for f in out.flaws if f.rule == flaw.rule
                          or (flaw.source in _DEATH and f.source in _DEATH)), None)
            if again is None:
                missed["rules"] = out.rules()
                return None
            return again, out

        conf = self.confirm_logged(once, until_miss=True, share=False)  # bounded by the deadline alone
        if not conf.confirmed:
            seen_instead = missed.get("rules")
            self.not_confirmed(flaw.rule, None, conf, shape=shape, actual=flaw.actual, why=(
                f"the minimal sequence of {len(minimal)} datagram(s) showed it in triage, then not in confirmation "
                f"replay {len(conf.results)} (pace {pace}; timing or load)"
                + (f"; seen instead: {', '.join(sorted(seen_instead))}" if seen_instead else "")))
            return None
        (seen, outcome), _ = conf.hits[0]
        final_shape = shape_of(seen, [Input.of(d) for d in minimal]) if flaw.source in _DEATH else shape
        self.aliases[(flaw.rule, shape)] = (seen.rule, final_shape)
        if self.store.known(seen.rule, final_shape):
            self.store.count(seen.rule, final_shape)
            return None
        traffic = [(r.direction, r.t_ns, r.data, r.addr) for r in outcome.traffic]
        finding = Finding.from_flaw(seen, minimal, final_shape, self.engine, self.seed, pace,
                                    worker=self.worker, program=program, scenario=scenario,
                                    target=self._target_doc())
        self.store.add(finding, traffic)
        return finding
