"""The suite's schedule (issue 23, docs/design.md "The suite's schedule"): which cases share time
and which run alone, and why — a plan that is data, printed by ``-v`` and written into the
JSON report (``schedule``).

What only waits is overlapped; nothing is weakened to overlap:

- **a batch** (``shared``): the cases whose wall time is a watched window — "no reply" over
  the ACK window (D-6: MCP-ACK-4/5/6, MCP-ROB-1..4) or a delivery count that must not grow
  (MCP-DUP-1/4, MCP-PAY-8) — run together, so their windows are watched once. Each probe is
  its own: a reply is tied to a probe by the seq it names (``judge.attribution``), a
  delivery by its probe's token, so each case still judges only its own traffic; a case
  whose messages must reach the node with nothing between them (MCP-DUP-1's message and its
  copy: the copy of the one last delivered) holds the others' sends back meanwhile
  (``conformance._batch.InARow``), so a node sees them as it would alone. A batch is
  kept only when it ran *clean*: every case of it passed (or was skipped before sending),
  the node stayed live, and every datagram the node sent meanwhile was an ACK that names
  the seq of a command it had to answer, no more of them than copies of such commands.
  Anything else (a failure, a reply tied by timing only or ambiguously, a node lost or
  silent) and the batch's verdicts are thrown away and its cases run again one by one, in
  their serial order: a fault one probe provokes is never blamed on another, and the
  verdicts are the serial run's (``batch_outcome``). Cases whose verdict depends on what
  came just before (an ACK's form, duplicates of the message before) stay alone: beside
  others' commands such a fault can hide (``JUDGES_ORDER``);
- **alone**: everything else, each with its reason (mission state, restarts, floods,
  latency, the startup's and the whole run's observations).

The startup phase is not overlapped: while Mission_Ready's ACK is withheld a node may be
deaf (D-6: it blocks in its send), and the watch for copies after the right ACK (MCP-RTX-1)
is also the time a node has to arm before Start_Mission (MCP-BLK-4): Start_Mission sent at
once would hide a node that arms as soon as its Mission_Ready is ACKed, and commands sent
before it would be sent to a node whose mission has not started.

``--serial`` runs every case alone in the order of their modules (the schedule the runner
had before; the comparison of the two is ``bench/bench_suite.py`` and
``tests/conformance/test_schedule_verdicts.py``).

**Shards** (``mcp-conform --parallel N``, spawn mode; ``shard_plan``): the plan's units (a
case alone, the batch as one) are shared out across up to N node instances, each spawned on
ports of its own, longest first onto the instance that would finish first, by an estimate in
units of the node's timeout (``--rto``) and the ACK window where those are what a unit waits
(``estimate``; the batch's window once). Each instance runs its own startup phase. The
observed one is made of three waits (``PARTS``, harness.drone_session.STARTUP_PARTS): the fix
held (MCP-BLK-5), Mission_Ready's copies while the ACK is withheld with the watch after the
right ACK (MCP-RTX-1's two halves; that watch is also MCP-BLK-4's time to arm, so MCP-BLK-4,
``STARTUP_BOUND``, goes with it), and the wrong ACKs (MCP-RTX-2: two copies, which show the
node's period, then the wrong ACKs and a copy awaited). Each part is observed on one
instance, as in the whole phase but without the others' waits, and each case judged on a
part (``part_of``) runs there; the parts go together or apart, whichever way leaves the
instances' estimates, longest first, the least (at ``--rto 5``: the copies and the watch,
17.5 s, alone; the wrong ACKs, 10 s, and the fix, 4 s, elsewhere). The instance with the
longest startup is the first (started first; the others ``STAGGER_S`` later). Nothing of a
startup is overlapped with cases on its instance (D-6: a node may be deaf while its
Mission_Ready's ACK is withheld). An instance that observes no part runs the quick startup
of a restart (the first Mission_Ready ACKed at once, a header that reads right only
byte-swapped still diagnosed). Within an instance, cases that run alone still run alone and the batch stays
whole. The cases judged on the whole run's traffic (the ``late`` phase's observations) run
on every instance, each on its own node's traffic (``shard`` None), and the worst verdict
is the case's: the run's traffic is the union of the instances'. Nothing else changes what
a case sees, so its verdict is the run of one's (``tests/conformance/test_parallel.py``).
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass

from mcp_conform.spec import SPEC
from mcp_conform.spec.profiles import pick, profile_of_role

__all__ = ["BATCH", "PARTS", "PASSTHROUGH_CASES", "Plan", "Step", "estimate", "part_of", "plan_cases",
           "shard_plan"]

#: MCP-RTX-1's copies while the ACK is withheld (the spec's ``min_copies``)
MIN_COPIES = int(SPEC.params["min_copies"])

SILENCE = ("waits out a 'no reply' window (D-6); its probes are told apart from the batch's others "
           "by the seq each reply names")
COUNT = ("waits out a delivery-count window; its probes carry tokens of their own, counted one by "
         "one by the vehicle")
MALFORMED = SILENCE + "; a node lost to one input makes the batch run again case by case"

#: the cases that only wait, and why they can share their window
BATCH_CASES: dict[str, str] = {
    "ACK/test_broadcast_is_not_acked": SILENCE,
    "ACK/test_message_to_another_id_is_neither_acked_nor_acted_on": SILENCE,
    "ACK/test_an_ack_is_never_acked": SILENCE,
    "DUP/test_same_seq_twice_is_delivered_once": COUNT,
    "DUP/test_late_copy_of_an_older_message": COUNT,
    "PAY/test_passthrough_frame_reaches_the_autopilot_once": COUNT,
    "ROB/test_short_datagrams_are_discarded": MALFORMED,
    "ROB/test_bad_preamble_is_discarded": MALFORMED,
    "ROB/test_unknown_action_code_is_discarded": MALFORMED,
    "ROB/test_payload_that_does_not_fit_is_not_acked": MALFORMED,
}
#: the batch's cases that first learn whether the node forwards Mav_Passthrough frames
#: (``CaseContext.require_passthrough``): learnt before the batch starts, alone
PASSTHROUGH_CASES = ("DUP/test_same_seq_twice_is_delivered_once", "DUP/test_late_copy_of_an_older_message",
                     "PAY/test_passthrough_frame_reaches_the_autopilot_once")
#: malformed input: shared only when a lost node can be restarted (spawn mode)
CRASHABLE = frozenset(c for c, why in BATCH_CASES.items() if why is MALFORMED)

#: why a case runs alone (by case ID; the others: "nothing to overlap")
ALONE: dict[str, str] = {
    "ROB/test_flood_of_malformed_datagrams": "a flood: alone, it would bury other cases' probes",
    "SEQ/test_zero_after_65535_is_new": "moves the runner's seq across the wrap and may leave the node "
                                        "unusable (a fresh node follows): alone",
    "ROB/test_unexpected_messages_are_survived": "a second Start_Mission and other mission-state "
                                                 "messages: alone",
    "ROB/test_datagrams_of_0_and_65507_bytes_are_survived": "inputs that may crash the node, and no "
                                                            "window to share: alone",
    "ACK/test_ack_leaves_within_the_deadline": "measures ACK latency: other traffic would skew it",
    "DUP/test_same_seq_from_another_src_is_not_a_duplicate": "sends as another source and moves that "
                                                             "source's seq: alone",
    "BLK/test_end_mission_then_rtl": "End_Mission ends the mission: last, alone",
}
PHASE_WHY = {
    "startup": "judged on the startup phase's observation; sends nothing",
    "late": "judged on the whole run's traffic: after the cases that make it",
    "end": "ends the mission: last, alone",
}
NOTHING = "nothing to overlap (no window worth sharing): alone"
#: why the quick cases that judge the form of the node's ACKs or its duplicate detection are
#: not shared even though a batch runs anyway: beside others' commands a node that names the
#: previous message's seq in its ACK names another open command's (MCP-ACK-2 passed beside
#: them), and one that takes a message with the bytes of the one before for a duplicate
#: sees other messages between the two (MCP-DUP-2 passed)
JUDGES_ORDER = {
    "ACK/test_every_retransmitted_copy_is_acked": "judges each copy's ACK: alone, so no other command is open "
                                                  "beside it (a reply naming another's seq would look right)",
    "ACK/test_ack_payload_is_the_big_endian_seq": "judges the ACK's payload: alone, so no other command is open "
                                                  "beside it (a node naming the previous message's seq would "
                                                  "name another open command's)",
    "ACK/test_ack_is_addressed_back_to_the_sender": "judges the ACK's form: alone, so each reply is tied to its "
                                                    "command by order as well as seq",
    "DUP/test_new_seq_with_the_same_bytes_is_delivered": "judges duplicate detection on two messages in a row: "
                                                         "alone, other messages between them would hide a node "
                                                         "that compares bytes",
}
BATCH = "batch"
#: cases judged on the observed startup phase beyond the ``startup`` phase's own: they run on
#: the instance that observes it (``shard_plan``)
STARTUP_BOUND = {
    "BLK/test_no_arming_before_start_mission": "judged on the observed startup's Start_Mission: on the "
                                               "instance that observes the startup phase",
}
EVERY = ("judged on the whole run's traffic: on every instance, each on its own node's traffic; "
         "the worst verdict is the case's")
#: the observed startup's parts (harness.drone_session.STARTUP_PARTS): the fix withheld
#: (MCP-BLK-5), Mission_Ready's copies and the watch after the right ACK (MCP-RTX-1, ...,
#: MCP-BLK-4's time to arm), the wrong ACKs (MCP-RTX-2)
PARTS = ("fix", "copies", "wrong")
#: the part a startup-bound case is judged on, where it is not ``copies``
PART_OF = {
    "BLK/test_no_mission_ready_without_a_gps_fix": "fix",
    "RTX/test_only_the_right_ack_ends_retransmission": "wrong",
}


def part_of(case: str) -> str:
    """The observed startup's part a startup-bound case is judged on (``PARTS``)."""
    return PART_OF.get(case, "copies")


@dataclass(frozen=True)
class Step:
    """One case in the plan: its group (``startup``, ``alone``, ``batch``, ``late``,
    ``end``), whether it shares its time with the other cases of its group, and why."""

    case: str
    group: str
    shared: bool
    why: str
    shard: int | None = 0  # the node instance it runs on (``--parallel``); None: on every one

    def to_json(self) -> dict[str, object]:
        return {"case": self.case, "group": self.group, "shared": self.shared, "why": self.why,
                "shard": self.shard}


@dataclass
class Plan:
    """The run's schedule: the cases in the order they run, and what became of the batch
    (``batch_outcome``: "kept", or why its cases ran again one by one)."""

    mode: str  # "scheduled" or "serial"
    why: str  # why this mode
    steps: list[Step]
    batch_outcome: str | None = None
    shards: int = 1  # node instances (``--parallel``)

    @property
    def batch(self) -> list[str]:
        return [s.case for s in self.steps if s.group == BATCH]

    def to_json(self) -> dict[str, object]:
        return {"mode": self.mode, "why": self.why, "batch_outcome": self.batch_outcome,
                "shards": self.shards, "steps": [s.to_json() for s in self.steps]}

    def lines(self) -> list[str]:
        """The plan for a person (``-v``); with shards, each step's node instance (1-based;
        ``all``: on every one)."""
        out = [f"schedule: {self.mode} ({self.why})"
               + (f", across {self.shards} node instances" if self.shards > 1 else "")]
        for s in self.steps:
            where = "" if self.shards <= 1 else f"{'all' if s.shard is None else s.shard + 1:>3} "
            out.append(f"  {where}{s.group:<7} {'shared' if s.shared else 'alone ':<6} {s.case}: {s.why}")
        return out

    def of_shard(self, shard: int) -> list[str]:
        """The cases instance ``shard`` runs, in the plan's order."""
        return [s.case for s in self.steps if s.shard is None or s.shard == shard]

    def startup_parts(self, shard: int) -> frozenset[str]:
        """The parts of the observed startup phase instance ``shard`` observes (``PARTS``: the
        parts its startup-bound cases are judged on); none: the quick startup."""
        return frozenset(part_of(s.case) for s in self.steps
                         if s.shard == shard and (s.group == "startup" or s.case in STARTUP_BOUND))

    def observes_startup(self, shard: int) -> bool:
        """Whether instance ``shard`` observes (a part of) the startup phase, else runs the
        quick one."""
        return bool(self.startup_parts(shard))

    @classmethod
    def from_json(cls, doc: dict) -> Plan:
        steps = [Step(str(s["case"]), str(s["group"]), bool(s["shared"]), str(s["why"]), s.get("shard", 0))
                 for s in doc.get("steps", [])]
        return cls(str(doc["mode"]), str(doc["why"]), steps, doc.get("batch_outcome"), int(doc.get("shards", 1)))


def serial_why(role: str | None, serial: bool, impaired: bool, worker: bool = False) -> str | None:
    """Why this run is not scheduled, or None when it is (``role``: its name, None: the
    default's; whether its cases are scheduled is its profile's, ``RoleProfile.scheduled``)."""
    if worker:
        return "a pytest-xdist worker: the workers share the cases out, each runs its share one by one"
    if serial:
        return "--serial: every case alone, in the order of their modules"
    prof = pick()[1] if role is None else profile_of_role(role).role(role)
    if not prof.scheduled:
        return f"the {prof.name} role's cases run one after another (not scheduled yet)"
    if impaired:
        return "--impair: a spoiled observation is repeated case by case"
    return None


def plan_cases(cases: Sequence[tuple[str, str]], *, role: str | None = None, spawned: bool = True,
               serial: bool = False, impaired: bool = False, worker: bool = False) -> Plan:
    """The plan for ``cases`` (case ID, phase), given in the serial order (by phase, then by
    module): the batch's cases run together where its first one stood, every other case
    keeps its place."""
    why_serial = serial_why(role, serial, impaired, worker)
    if why_serial is not None:
        steps = [Step(c, phase if phase in PHASE_WHY else "alone", False,
                      PHASE_WHY.get(phase, why_serial)) for c, phase in cases]
        return Plan("serial", why_serial, steps)
    shared: list[Step] = []
    steps_or_slot: list[Step | None] = []
    for c, phase in cases:
        why = BATCH_CASES.get(c)
        if phase == "main" and why is not None and (spawned or c not in CRASHABLE):
            if not shared:
                steps_or_slot.append(None)  # the batch runs where its first case stood
            shared.append(Step(c, BATCH, True, why))
            continue
        if why is not None and c in CRASHABLE:
            steps_or_slot.append(Step(c, "alone", False, "attach mode: a node lost to a malformed "
                                      "input cannot be restarted, so it is not risked beside others"))
            continue
        group = phase if phase in PHASE_WHY else "alone"
        why_alone = ALONE.get(c) or JUDGES_ORDER.get(c) or PHASE_WHY.get(phase) or NOTHING
        steps_or_slot.append(Step(c, group, False, why_alone))
    if len(shared) == 1:  # a batch of one shares nothing
        only = shared[0]
        shared = []
        steps_or_slot = [Step(only.case, "alone", False, NOTHING) if s is None else s for s in steps_or_slot]
    steps = []  # list[Step], as above
    for s in steps_or_slot:
        steps.extend(shared if s is None else [s])
    return Plan("scheduled", "what only waits is overlapped", steps)


# ---------------------------------------------------------------------- shards (--parallel)
#: a node's time to its first Mission_Ready once spawned (the process's start; not a timeout)
NODE_START_S = 1.0
#: a case that only exchanges a few datagrams with a node that answers at once
QUICK_CASE_S = 0.15
#: a window's cases beyond the window: the probes before it (whether the node forwards
#: Mav_Passthrough frames), the sends, the proof of life after it (4.1 to 4.4 s in all at a
#: 2 s window, bench/bench_suite.py)
BATCH_EXTRA_S = 1.0
#: the flood of malformed datagrams, sent and survived (0.3 to 0.4 s, bench/bench_suite.py)
FLOOD_S = 0.5
#: how much later than the first instance the others start their node: the first one's own
#: start and collection (they are started once it has planned, ``conformance.parallel``), and
#: theirs beside its work (4 to 6 s on a loaded 2-core host, bench/bench_suite.py)
STAGGER_S = 4.0


def startup_estimate(parts: Collection[str], rto: float, window: float) -> float:
    """The startup phase's wall time, estimated (harness.drone_session) for the observed
    startup's ``parts`` (none: the quick one): the fix held (2 windows, MCP-BLK-5); the
    copies awaited (MCP-RTX-1's 3: two retransmissions) and the watch after the right ACK (1.5
    timeouts, MCP-RTX-1, MCP-BLK-4); the wrong ACKs (MCP-RTX-2) one more copy after the
    copies, or two alone (the second shows the node's period); then Start_Mission, ACKed
    at once."""
    t = NODE_START_S
    if "fix" in parts:
        t += max(2 * window, 0.5)
    if "copies" in parts:
        t += (MIN_COPIES - 1) * rto + max(window, 1.5 * rto)
    if "wrong" in parts:
        t += rto if "copies" in parts else 2 * rto
    return t


def estimate(step: Step, rto: float, window: float) -> float:
    """A step's wall time, estimated in units of what it waits: a silence or count window
    (the batch's, shared), else the few exchanges of a quick case; a case judged on the
    startup's observation, nothing."""
    if step.group == "startup" or step.case in STARTUP_BOUND:
        return 0.0
    if step.group == BATCH or step.case in BATCH_CASES:  # (alone: its own window)
        return 1.5 * window + BATCH_EXTRA_S
    if step.case == "ROB/test_flood_of_malformed_datagrams":
        return FLOOD_S
    return QUICK_CASE_S


def _partitions(items: list[str]) -> list[list[list[str]]]:
    """Every way to split ``items`` into groups (the order of the items kept in each)."""
    if not items:
        return [[]]
    first, out = items[0], []
    for rest in _partitions(items[1:]):
        out.append([[first], *rest])
        out += [[*rest[:i], [first, *rest[i]], *rest[i + 1:]] for i in range(len(rest))]
    return out


def _unit_estimate(unit: list[Step], rto: float, window: float) -> float:
    """A unit's wall time: the batch's window once (its cases share it), else its case's."""
    return estimate(unit[0], rto, window) if unit[0].group == BATCH else sum(estimate(s, rto, window) for s in unit)


def _spread(units: list[list[Step]], loads: list[float], rto: float, window: float) -> dict[str, int]:
    """Each unit onto the instance estimated to finish first, longest first (``loads``
    updated); ties keep the plan's order (a stable sort), so the plan is the same in every
    process that makes it."""
    where: dict[str, int] = {}
    for unit in sorted(units, key=lambda u: -_unit_estimate(u, rto, window)):
        k = min(range(len(loads)), key=lambda i: (loads[i], i))
        loads[k] += _unit_estimate(unit, rto, window)
        for s in unit:
            where[s.case] = k
    return where


def shard_plan(plan: Plan, shards: int, rto: float, window: float) -> Plan:
    """``plan`` shared out across at most ``shards`` node instances (see the module's
    docstring): the observed startup's parts (``PARTS``) together or on instances of their
    own, each startup-bound case with its part, the whole run's observations on every
    instance, the rest unit by unit (the batch one unit), longest first, each onto the
    instance estimated to finish first. Of the ways to share the parts out, the one whose
    instances' estimates, longest first, are the least. The longest startup goes on the
    first instance (started first); instances left with nothing of their own are not used."""
    if shards <= 1:
        return plan
    steps = plan.steps
    bound = [s for s in steps if s.group == "startup" or s.case in STARTUP_BOUND]
    every = {s.case for s in steps if s.group == "late" and s.case not in ALONE and s.case not in STARTUP_BOUND}
    units: list[list[Step]] = []
    batch = [s for s in steps if s.group == BATCH]
    if batch:
        units.append(batch)
    units += [[s] for s in steps if s.group != BATCH and s not in bound and s.case not in every]
    needed = [p for p in PARTS if any(part_of(s.case) == p for s in bound)]
    best: tuple[list[float], dict[str, int]] | None = None
    for blocks in sorted(_partitions(needed), key=len):
        if len(blocks) > shards:
            continue
        blocks.sort(key=lambda b: -startup_estimate(b, rto, window))  # stable: the parts' order on a tie
        loads = [startup_estimate(blocks[k] if k < len(blocks) else (), rto, window) + (STAGGER_S if k else 0.0)
                 for k in range(shards)]
        where = {s.case: next(k for k, b in enumerate(blocks) if part_of(s.case) in b) for s in bound}
        where.update(_spread(units, loads, rto, window))
        used = set(where.values()) or {0}
        key = sorted((round(2 * loads[k]) / 2 for k in used), reverse=True)  # to half a second
        if best is None or key < best[0]:  # (fewer groups first: a tie keeps the parts together)
            best = (key, where)
    assert best is not None
    where = best[1]
    number = {k: n for n, k in enumerate(sorted(set(where.values()) or {0}))}
    out = [Step(s.case, s.group, s.shared, EVERY if s.case in every else s.why,
                None if s.case in every else number[where[s.case]]) for s in steps]
    return Plan(plan.mode, plan.why, out, plan.batch_outcome, len(number))
