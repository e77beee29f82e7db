"""The protocol-neutral steps of every protocol's triage (issue 37: one triage; issue 39: a
protocol's plumbing near zero), written once: MCP's (``fuzz.triage``), MAVLink's
(``fuzz.mavlink_triage``) and Nsqd's (``fuzz.nsqd_triage``) declare only what is their own --
how a fresh target starts (each counted a ``triage replay`` restart: :meth:`HitTriage.fresh`),
how inputs are replayed (``replay(inputs) -> signature | None``, :meth:`HitTriage.shows`;
``replay(log)`` for step 4, :meth:`HitTriage.confirm_logged`), what their oracles observe,
which oracles end a target (``DEATHS``), which tries come first, what one input is made of
(:class:`Parts`), how a finding is written.

From a hit to a finding (``fuzz.confirm`` lists the loop's steps):

1. counted, not triaged (:meth:`HitTriage.counted`): its group is already a finding (its
   ``occurrences`` counted), its signature did not reproduce ``UNCONFIRMED_TRIES`` times, or
   triage's budget is spent (``fuzz.budget``: counted ``untriaged``); a hit that lasts once
   shown is a known finding's when one of its suspects like that finding's confirmed input is
   its culprit (:meth:`HitTriage.known_lasting`, :func:`known_lasting_hit`: two sends to one
   fresh target, not a search); a known finding's hit is one more occurrence of it
   (:meth:`HitTriage.again`); the same observation with no input, once a worker, confirmed, is
   a finding with no input blamed (:meth:`HitTriage.no_input`, :meth:`HitTriage.baseline`);
2. each replay counted and bounded (:meth:`HitTriage.replay`: none after the deadline, ``Late``);
3. the suspects searched for the fewest that show it, one search (:func:`search`): the tries
   in order (each suspect alone, the newest first, unless a protocol names others), else all
   of them, delta debugged (``fuzz.ddmin``), then one input's parts; the newest confirmed at
   once where it is the usual culprit (:meth:`HitTriage.minimal`); a death whose cause shows
   late, among every input its target was sent (:func:`prefix_culprit`: the shortest prefix
   that shows it, by bisection); a hit that lasts once shown (a stopped heartbeat, a stream
   that stays lost) by bisection over the suspects' prefixes (:func:`earliest_prefix`: log2 n
   replays, not n). What a replay shows is no finding yet: step 4;
4. the minimal input replayed N more times, each on a fresh target (``fuzz.confirm``,
   :meth:`HitTriage.confirm_logged`), or not a finding (:meth:`HitTriage.missed`,
   :meth:`HitTriage.not_confirmed`: counted, its tries noted, and named environment-dependent
   with why when it showed in triage).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar, Generic, TypeVar

from mcp_conform.fuzz.budget import UNCONFIRMED_TRIES, budget_left, check_late
from mcp_conform.fuzz.confirm import Confirmation, confirm_n
from mcp_conform.fuzz.ddmin import ddmin
from mcp_conform.fuzz.findings import Finding
from mcp_conform.fuzz.loop import Triage, count, triage_time
from mcp_conform.fuzz.target_base import TargetLost
from mcp_conform.harness.errors import SetupError

__all__ = ["Parts", "HitTriage", "answered", "culprit", "earliest_prefix", "fewest", "known_lasting_hit", "prefix_culprit", "search"]

T = TypeVar("T")
P = TypeVar("P")
H = TypeVar("H")
K = TypeVar("K")
C = TypeVar("C", bound="HitTriage")


@dataclass(kw_only=True, eq=False)
class HitTriage(Triage):
    """A worker's triage state every protocol keeps (its counts: ``fuzz.loop.Triage``): its
    seed and worker (a finding's), the N of N, and the signatures that did not reproduce;
    what an engine's turn learnt is carried to the next one's (:meth:`carry`: the fields
    ``LEARNT`` names, ``tries`` among them); its findings (:attr:`findings`) and the target now
    fuzzed (:attr:`current`) are its store's and its worker target's."""

    LEARNT: ClassVar[tuple[str, ...]] = ("tries", "baselines")
    #: the oracles of a hit that ended its target (it died, hung or stopped answering): the
    #: target is restarted after one, and its finding named by the input that makes it
    DEATHS: ClassVar[tuple[str, ...]] = ()

    #: the worker's target (``fuzz.loop.WorkerTarget``, MCP's ``fuzz.target_base.TargetBase``)
    #: and the campaign's findings (``fuzz.findings.FindingStore``)
    target: Any = None
    store: Any = None
    seed: int = 0
    worker: int = 0
    n_of_n: int = 3  # a finding's confirming replays, all of which must show it
    tries: dict[Any, int] = field(default_factory=dict)  # a hit's key -> triages that did not reproduce
    #: what each baseline of the worker showed, confirmed (:meth:`baseline`; None: nothing)
    baselines: dict[Any, Any] = field(default_factory=dict)

    def carry(self: C) -> C:
        """The next engine's turn's triage: what this one learnt (``LEARNT``) kept, with its
        target, store, seed, worker, N of N and the campaign's bound; its counts new."""
        kept = {f.name: getattr(self, f.name) for f in fields(self)
                if f.name in self.LEARNT or f.name in ("seed", "worker", "n_of_n", "started", "duration")
                or f.name in ("target", "store")}
        return type(self)(**kept)

    @property
    def findings(self) -> list[Finding]:
        """The worker's findings so far, in the order kept (its store's)."""
        return self.store.order  # type: ignore[no-any-return]

    @property
    def current(self) -> Any:
        """The target now fuzzed (the worker target's ``current``, ``fuzz.loop.WorkerTarget``:
        a replay or a restart replaces it)."""
        return self.target.current

    @current.setter
    def current(self, t: Any) -> None:
        self.target.current = t

    def add(self, finding: Finding, *args: Any) -> None:
        """A confirmed finding into the store (``finding-N/`` under its ``out``), this
        worker's and seed's."""
        finding.seed, finding.worker = self.seed, self.worker
        self.store.add(finding, *args)

    def again(self, known: Finding | None) -> bool:
        """Whether a hit is ``known`` (the finding it already is): then one more occurrence of it."""
        if known is not None:
            known.occurrences += 1
        return known is not None

    def counted(self, known: Finding | None, key: Hashable, describe: str) -> bool:
        """Step 1: counted, not triaged -- ``known`` (the finding the hit already is: one more
        occurrence, :meth:`again`), a ``key`` tried ``UNCONFIRMED_TRIES`` times, or the budget
        spent (counted untriaged as ``describe``)."""
        if self.again(known):
            return True
        if self.tries.get(key, 0) >= UNCONFIRMED_TRIES or not budget_left(self, time.monotonic()):
            count(self.untriaged, describe)
            return True
        return False

    def replay(self, run: Callable[[], T], *, share: bool = True) -> T:
        """Step 2: one replay, counted; none once the deadline passed (or, ``share``, triage's
        share of the campaign: ``Late``)."""
        check_late(self, share=share)
        self.replays += 1
        return run()

    def fresh(self, make: Callable[[], T]) -> T:
        """A fresh target for a replay of triage's (``make()``: a new process, or a new link
        when attached), counted as the target's ``triage replay`` restart."""
        try:
            return make()
        finally:
            self.target.count_restart("triage replay")

    def shows(self, replay: Callable[[list[T]], H | None], same: Callable[[H], bool] = lambda h: True,
              *, share: bool = True, unstarted: bool = False) -> Callable[[list[T]], bool]:
        """Step 3's one predicate, over a protocol's ``replay(inputs)``: what the inputs showed
        replayed on a fresh target (its signature; None: nothing, or, ``unstarted``, a target
        that did not start: SetupError), each replay counted and bounded (:meth:`replay`);
        whether it is ``same`` as the hit triaged. What a replay shows is not thereby a
        finding: step 4 confirms it."""
        def run(inputs: list[T]) -> H | None:
            try:
                return replay(list(inputs))
            except TargetLost:
                raise  # attach mode's only target gone: the campaign ends (never "did not start")
            except SetupError:
                if not unstarted:
                    raise
                return None

        def test(inputs: list[T]) -> bool:
            h = self.replay(lambda: run(inputs), share=share)
            return h is not None and same(h)
        return test

    def minimal(self, suspects: list[T], shows: Callable[[list[T]], bool],
                confirm: Callable[[list[T], bool], Confirmation[Any]], *,
                lasting: tuple[Callable[[], Any], Callable[[Any, Sequence[T]], bool | None], Callable[[Any], None],
                               float] | None = None,
                group: Callable[[T], Hashable] | None = None, parts: Parts[T, Any] | None = None,
                budget: int = 24, singles: int = 0) -> tuple[list[T], Confirmation[Any]] | None:
        """Steps 3 and 4 when the newest suspect is the usual culprit: it is confirmed at once
        (``confirm(inputs, until_miss)``, until the first miss: N replays, none more), then its
        fewest ``parts`` (kept when confirmed again: :meth:`shorter`); when it is not, the fewest
        of every suspect that show it (:func:`search`: no tries, every suspect together, a
        ``group`` alone first, delta debugging within ``budget``, ``singles``; then ``parts``),
        confirmed (all N: how often it shows). ``lasting`` (``fresh``, ``extend``, ``close``,
        ``split``): a hit that lasts once shown, its suspects first cut to their shortest prefix
        that shows it (:func:`earliest_prefix`; a target that did not start: no verdict). The
        minimal input and its confirmation (a miss too: the caller names it); None when no
        input showed it in the search (not confirmed either)."""
        if lasting is not None and len(suspects) > 1:
            fresh, extend, close, split = lasting
            try:
                n = earliest_prefix(suspects, fresh, extend, close, split=split)
            except TargetLost:
                raise
            except SetupError:
                n = None
            if n is None:
                return None
            suspects = suspects[:n]
        first = suspects[-1:]
        conf = confirm(first, True)
        if conf.confirmed:
            return self.shorter(first, conf, lambda: [fewer_parts(first[0], shows, parts)] if parts and first else first,
                                confirm)
        found = search(suspects, shows, tries=[], whole=len(suspects) > 1, budget=budget, singles=singles, group=group,
                       parts=parts)
        return None if found is None else (found, confirm(found, False))

    @staticmethod
    def shorter(minimal: list[T], conf: Confirmation[Any], cut: Callable[[], list[T]],
                confirm: Callable[[list[T], bool], Confirmation[Any]]) -> tuple[list[T], Confirmation[Any]]:
        """A confirmed minimal input cut shorter (``cut()``: its fewest parts, a shorter tail),
        kept only when it is confirmed as the whole was (all N: ``confirm(inputs, False)``);
        else the input as it was, with its own confirmation."""
        fewer = cut()
        if fewer != minimal:
            again = confirm(fewer, False)
            if again.confirmed:
                return fewer, again
        return minimal, conf

    def triaged(self, describe: str, triage: Callable[[], object], restart: Callable[[], object] | None = None) -> Any:
        """One hit's triage (``triage()``), timed (``fuzz.loop.triage_time``: past the deadline
        or the budget it ends there, counted untriaged as ``describe``); ``restart``: the hit
        ended its target, restarted after it to go on fuzzing (:meth:`restarted`). The target now
        fuzzed (:attr:`current`), which triage's replays and restarts replace."""
        with triage_time(self, describe):
            triage()
        if restart is not None:
            self.restarted(restart)
        return self.current

    def restarted(self, restart: Callable[[], T]) -> T:
        """The target restarted to go on fuzzing after a hit (``restart()``), timed on its own
        (``restart_seconds``): a restart after a hit counted, not triaged, is no triage."""
        t0 = time.monotonic()
        try:
            return restart()
        finally:
            self.restart_seconds += time.monotonic() - t0

    def confirm_logged(self, replay: Callable[[Any], H | None], *, until_miss: bool, log: Callable[[], Any] = list,
                       share: bool = True) -> Confirmation[tuple[H, Any]]:
        """Step 4: ``replay(log)`` run ``n_of_n`` times (``fuzz.confirm``; ``until_miss``: none
        after the first miss), each a replay of triage's (:meth:`replay`: counted, bounded;
        ``share``), each with a ``log()`` of its own for the traffic it saw (a finding's repro
        files keep the last one's); a hit: (what it showed, its log)."""
        def once() -> tuple[H, Any] | None:
            seen = log()
            h = self.replay(lambda: replay(seen), share=share)
            return None if h is None else (h, seen)
        return confirm_n(once, self.n_of_n, until_miss=until_miss)

    def baseline(self, key: Hashable, observe: Callable[[list[Any], H | None], H | None], same: Callable[[H, H], bool],
                 found: Callable[[H, H, list[Any], str], None], describe: Callable[[H], tuple[str, str, str]],
                 shown: Callable[[], object] | None = None) -> H | None:
        """Blame (issue 36 item 2): the same observation without the input, on a fresh target
        sent nothing, run once a worker for each ``key`` (what it showed kept in ``baselines``
        for the next hits and engine turns). ``observe(log, first)``: one baseline on a fresh
        target, its traffic into ``log`` (``first``: what the first showed, None for the first);
        nothing shown: None, the input is to blame. Shown, it is confirmed by ``n_of_n - 1``
        more baselines, all of them (``until_miss`` off: how often it shows), each ``same`` as
        the first: then the target's behaviour, a finding with no input blamed
        (``found(first, last, last's log, "N of N")``), and the first's hit returned; not every
        time: counted unconfirmed under its rule, named environment-dependent
        (``describe(first)``: rule, shape, actual), and None (no input is to blame either).
        ``shown()``: after a baseline that showed something (the target to go on with). Each
        baseline a replay of triage's (counted, none after the deadline; triage's share aside)."""
        if key in self.baselines:
            return self.baselines[key]  # type: ignore[no-any-return]
        log: list[Any] = []
        first = self.replay(lambda: observe(log, None), share=False)
        if first is not None:
            shown_first: H = first

            def once() -> tuple[H, list[Any]] | None:
                more: list[Any] = []
                h = self.replay(lambda: observe(more, shown_first), share=False)
                return (h, more) if h is not None and same(h, shown_first) else None

            conf = confirm_n(once, self.n_of_n - 1, until_miss=False)  # the first is one of the N
            if conf.confirmed:
                last, last_log = conf.hits[-1] if conf.hits else (first, log)
                found(first, last, last_log, f"{1 + len(conf.hits)} of {self.n_of_n}")
            else:
                rule, shape, actual = describe(first)
                self.count_unconfirmed(rule)
                conf.note(self.environment, rule, shape, actual, "a baseline sent nothing showed it, then not "
                          "every confirming baseline did (timing or load); no input is to blame either")
                first = None
            if shown is not None:
                shown()
        self.baselines[key] = first
        return first

    def no_input(self, key: Hashable, observe: Callable[[list[Any], H | None], H | None], same: Callable[[H, H], bool],
                 finding: Callable[[H, H, list[Any], str], Finding | None], describe: Callable[[H], tuple[str, str, str]],
                 shown: Callable[[], object] | None = None) -> H | None:
        """:meth:`baseline`, its confirmed behaviour kept as a finding with no input blamed:
        ``finding(first, last, last's log, "N of N")`` (None: none new), added (:meth:`add`)."""
        def found(first: H, last: H, log: list[Any], replays: str) -> None:
            f = finding(first, last, log, replays)
            if f is not None:
                self.add(f)
        return self.baseline(key, observe, same, found, describe, shown)

    def known_lasting(self, suspects: Sequence[T], source: str, like: Callable[[T], Hashable], fresh: Callable[[], Any],
                      extend: Callable[[Any, Sequence[T]], bool | None], close: Callable[[Any], None]) -> bool:
        """Step 1 for a hit that lasts once shown (of oracle ``source``): whether it repeats a
        finding of that oracle, one of the ``suspects`` ``like`` its confirmed input's last
        the culprit (:func:`known_lasting_hit`, on fresh targets; one that did not start: no);
        then one more occurrence of it (:meth:`again`)."""
        knowns = [(f, like(f.cases[-1])) for f in self.findings if f.source == source and f.cases]
        try:
            return bool(knowns) and self.again(known_lasting_hit(suspects, knowns, like, fresh, extend, close))
        except TargetLost:
            raise
        except SetupError:  # a fresh target that did not start: triage it
            return False

    def missed(self, rule: str, key: Hashable, conf: Confirmation[Any], *, shape: str, actual: str, size: str,
               where: str = "") -> bool:
        """Step 4's verdict on an input that showed it in triage (``size``: how much of it):
        whether its confirming replays missed it (not N of N); then :meth:`not_confirmed`,
        named environment-dependent (timing or load)."""
        if conf.confirmed:
            return False
        self.not_confirmed(rule, key, conf, shape=shape, actual=actual,
                           why=f"the minimal input ({size}) showed it in triage, then {len(conf.hits)} of "
                               f"{self.n_of_n} confirming replays{where} did (timing or load)")
        return True

    def not_confirmed(self, rule: str, key: Hashable | None, conf: Confirmation[Any] | None = None, *, shape: str = "",
                      actual: str = "", why: str = "") -> None:
        """Step 4's miss: counted unconfirmed under ``rule``, ``key`` tried once more (None: a
        triage that keeps no tries); with ``conf`` (the confirming replays of an input that
        showed it in triage) named environment-dependent, with ``why``."""
        self.count_unconfirmed(rule)
        if key is not None:
            self.tries[key] = self.tries.get(key, 0) + 1
        if conf is not None:
            conf.note(self.environment, rule, shape, actual, why)


@dataclass(frozen=True)
class Parts(Generic[T, P]):
    """What one input is made of, for :func:`fewest`'s last step (a MAVLink case's frames,
    an Nsqd case's writes): ``split(input)``, ``join(input, parts)`` (the input with only
    those parts), at most ``budget`` replays."""

    split: Callable[[T], Sequence[P]]
    join: Callable[[T, list[P]], T]
    budget: int


def culprit(suspects: Sequence[T], shows: Callable[[list[T]], bool], *, tries: Sequence[Sequence[T]] | None = None,
            whole: bool = True) -> list[T] | None:
    """Step 3, first half: the input(s) among ``suspects`` (oldest first) that show the hit,
    each try a replay (``shows``: :meth:`HitTriage.shows`). The ``tries`` in order (default:
    each suspect alone, the newest first: the usual culprit), the first that shows it; else
    every suspect together (``whole``, unless it was one of the tries: they are the culprit,
    for :func:`fewest`); None when none of them shows it."""
    return _culprit(suspects, shows, tries, whole)[0]


def _culprit(suspects: Sequence[T], shows: Callable[[list[T]], bool], tries: Sequence[Sequence[T]] | None,
             whole: bool) -> tuple[list[T] | None, bool]:
    """:func:`culprit`, and whether it is every suspect together (the whole)."""
    tried = [list(t) for t in ([[s] for s in reversed(suspects)] if tries is None else tries)]
    for t in tried:
        if shows(t):
            return t, False
    if whole and suspects and list(suspects) not in tried and shows(list(suspects)):
        return list(suspects), True
    return None, False


def fewest(inputs: list[T], shows: Callable[[list[T]], bool], *, budget: int, singles: int = 0,
           group: Callable[[T], Hashable] | None = None, parts: Parts[T, Any] | None = None) -> list[T]:
    """Step 3, second half: the fewest of ``inputs`` (which show the hit) that still show it,
    each try a replay (``shows``). ``group``: with more than 8 inputs of several groups, the
    inputs of one group alone first (the newest input's group first: a heartbeat's suspects
    are many, one kind makes it); then delta debugging (``fuzz.ddmin``: ``budget`` replays,
    ``singles`` of the newest alone first); one input left, its fewest ``parts``. An input
    returned is one that showed it, or ``inputs`` themselves."""
    if group is not None and len(inputs) > 8:
        keys = list(dict.fromkeys(group(i) for i in reversed(inputs)))
        for k in keys if len(keys) > 1 else []:
            some = [i for i in inputs if group(i) == k]
            if len(some) < len(inputs) and shows(some):
                inputs = some
                break
    if budget:
        inputs = ddmin(list(inputs), shows, budget=budget, singles=singles)
    if parts is not None and len(inputs) == 1:
        inputs = [fewer_parts(inputs[0], shows, parts)]
    return inputs


def fewer_parts(item: T, shows: Callable[[list[T]], bool], parts: Parts[T, Any]) -> T:
    """The fewest ``parts`` of one input that still show the hit (delta debugging within
    ``parts.budget`` replays); ``item`` itself when none can go."""
    whole = list(parts.split(item))
    if len(whole) < 2:
        return item
    kept = ddmin(whole, lambda ps: shows([parts.join(item, ps)]), budget=parts.budget)
    return item if len(kept) == len(whole) else parts.join(item, kept)


def search(suspects: Sequence[T], shows: Callable[[list[T]], bool], *, tries: Sequence[Sequence[T]] | None = None,
           whole: bool = True, budget: int, singles: int = 0, group: Callable[[T], Hashable] | None = None,
           parts: Parts[T, Any] | None = None) -> list[T] | None:
    """Step 3 whole, the one search every protocol's triage runs: :func:`culprit`, then its
    :func:`fewest` (every suspect together delta debugged, a try as it is; one input left,
    its parts); None when none of them shows it. Each input list is replayed once in a
    search (:func:`answered`): a try asked again -- a suspect that is also a try of its own
    (MCP's vehicle flaw), delta debugging's singles after the same single tried as a
    suspect -- has its answer already."""
    shows = answered(shows)
    found, every = _culprit(suspects, shows, tries, whole)
    if found is None:
        return None
    return fewest(found, shows, budget=budget if every else 0, singles=singles, group=group, parts=parts)


def answered(shows: Callable[[list[T]], bool]) -> Callable[[list[T]], bool]:
    """``shows`` asked each input list once: a list asked again (equal to one asked before)
    gets the answer its replay gave, no second replay. The search (delta debugging) takes a
    replay's answer as the answer for that list; confirmation (step 4), which asks how often
    an input shows it, replays every time and never goes through this."""
    asked: list[tuple[list[T], bool]] = []

    def test(inputs: list[T]) -> bool:
        for before, verdict in asked:
            if before == inputs:
                return verdict
        verdict = shows(inputs)
        asked.append((list(inputs), verdict))
        return verdict
    return test


def known_lasting_hit(items: Sequence[T], knowns: Sequence[tuple[K, Hashable]], signature: Callable[[T], Hashable],
                      fresh: Callable[[], H], extend: Callable[[H, Sequence[T]], bool | None],
                      close: Callable[[H], None], most: int = 3) -> K | None:
    """Step 1 for a hit that lasts once shown (a stopped heartbeat), whose suspects ``items``
    are every input of a while, not the one that showed it: the first of ``knowns`` (a finding,
    the ``signature`` of the input its triage confirmed) whose like input is the culprit, None
    when none is (triage it). The culprit is what :func:`earliest_prefix` would find (the last
    item of the shortest prefix after which a target shows it), checked, not searched: one
    fresh target is sent the items before the first like one (False: they do not show it), then
    that one (True: it is the culprit, the known finding again), then those up to the next like
    one, ... for at most ``most`` like items. A repeat of a known hit costs two sends, not a
    search; a new hit is triaged even when inputs like a known one were among its suspects
    (an unlike item shows it first), and so is one no like item shows within ``most``.
    ``fresh``, ``extend``, ``close``: as for :func:`earliest_prefix`."""
    for known, sig in knowns:
        at = [i for i, item in enumerate(items) if signature(item) == sig][:most]
        if at and _culprit_among(items, at, fresh, extend, close):
            return known
    return None


def _culprit_among(items: Sequence[T], at: list[int], fresh: Callable[[], H],
                   extend: Callable[[H, Sequence[T]], bool | None], close: Callable[[H], None]) -> bool:
    """Whether one of ``items[i]``, ``i`` in ``at``, is the first after which one fresh target
    shows the hit (the items between sent in order, none of which may show it first)."""
    target = fresh()
    try:
        lo = 0
        for i in at:
            for more, its in ((items[lo:i], False), (items[i:i + 1], True)):
                verdict = extend(target, more) if more else False
                if verdict is None:  # the target is lost: no verdict
                    return False
                if verdict:  # shown: by the like item (the known culprit), or by one before it
                    return its
            lo = i + 1
        return False
    finally:
        close(target)


def earliest_prefix(items: Sequence[T], fresh: Callable[[], H], extend: Callable[[H, Sequence[T]], bool | None],
                    close: Callable[[H], None], split: float = 0.5) -> int | None:
    """Step 3 for a hit that lasts once shown: the length of the shortest prefix of ``items``
    after which a target shows it (its last item the culprit, or the one that completes it), by
    bisection; None when all of them do not show it, or a target is lost.

    ``fresh()``: a fresh target; ``extend(target, more)``: ``more`` sent to it after what it
    was sent before, True when it then shows the hit (the target is spent), False when not
    (the target, in the state those items left it, is sent the next ones: no fresh target and
    no wait for the hit), None when it is lost (no verdict). A target that showed it is
    replaced by a fresh one sent the shorter prefix at once. ``split``: the share of the
    range still in doubt that the next prefix adds (0.5: bisection, log2(n) replays; less when
    a replay that shows the hit costs more than one that does not: more replays, less time)."""
    if not items:
        return None
    lo, hi, shown = 0, len(items), False  # items[:lo] did not show it; items[:hi] did once ``shown``
    target: H | None = None  # sent items[:lo], still clean
    try:
        while not (shown and hi - lo <= 1):
            mid = min(hi, lo + max(1, round(split * (hi - lo))))
            if target is None:
                target, more = fresh(), items[:mid]
            else:
                more = items[lo:mid]
            verdict = extend(target, more)
            if verdict is None:
                return None
            if verdict:
                hi, shown = mid, True
                close(target)
                target = None
            else:
                lo = mid
                if lo >= hi:  # everything sent, and it did not show
                    return None
        return hi
    finally:
        if target is not None:
            close(target)


def prefix_culprit(items: Sequence[T], shows: Callable[[list[T]], bool], budget: int = 12) -> list[T] | None:
    """Step 3 for a death whose cause may show well after its input (a backend that handles
    its input behind the fuzzer): the input(s) of ``items`` (oldest first) it comes of, each
    try a replay on a fresh target (``shows``): the newest alone; else, when all of them show
    it, the shortest prefix that does, by bisection (log2 n replays), then its last item alone,
    else that prefix delta-debugged (``budget`` replays); None when all of them do not show it."""
    if shows(list(items[-1:])):
        return list(items[-1:])
    if not shows(list(items)):
        return None
    lo, hi = 0, len(items)  # the prefix of hi items shows it, of lo does not
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if shows(list(items[:mid])) else (mid, hi)
    if shows(list(items[hi - 1:hi])):
        return list(items[hi - 1:hi])
    return ddmin(list(items[:hi]), shows, budget=budget)
