"""The Nsqd stateful engine's programs: what clients of a one-client-at-a-time backend do,
drawn by a seeded ``random.Random`` (issue 36 item 4; ``fuzz.programs`` is MCP's).

A program is a list of ``fuzz.nsqd_stateful.Op``: it starts with a client's connect (slot
0), then valid commands (their effect judged, NSQD-MSG-3), mutated cases of any kind of
``fuzz.nsqd_mutators``, a second client's connect while the first is served (NSQD-CON-2,
D-4), a client's close (the waiting one is then served), a frame cut by FIN or RST
(NSQD-ROB-2) always followed by a new connection and a command on it (NSQD-ROB-3: what a
cut leaves behind shows only in the next stream, so a program never leaves it to the next
program's first bytes), and most often a command last, on the served client, whose effect
the program's end judges (``Player.finish``).

Ops are drawn by plain ``random`` calls (microseconds each), not by hypothesis's
rule-based machine (about 1 ms a step on the 2-core test host, a ceiling near 1,000 steps
per second before any byte was sent; ``fuzz.programs``). An op carries its bytes, so a
program saved in the example database (``--db``) replays on any worker as it was played.
"""

from __future__ import annotations

import contextlib
import json
import random
from collections.abc import Callable
from typing import Any

from mcp_conform.fuzz.engine_stateful import open_database
from mcp_conform.fuzz.loop import EngineStats, FuzzClock
from mcp_conform.fuzz.nsqd_backend import message_names
from mcp_conform.fuzz.nsqd_mutators import Write, draw_case
from mcp_conform.fuzz.nsqd_player import CLIENT_MSGS, COMMANDS, Hit, Op, Player, command_bytes
from mcp_conform.spec import NSQD

__all__ = ["DB_KEY", "StreamProgramGenerator", "StreamStatefulEngine", "dumps", "loads", "tried_kind"]

DB_KEY = b"mcp-fuzz/nsqd/stateful-programs"
STEPS = 20  # ops per program at most (the ops a cut brings along excluded)
#: (move, weight) of the ops after a program's first connect
_MOVES = (("cmd", 6), ("mutated", 5), ("second", 1), ("close", 1), ("cut", 1), ("reconnect", 1))
_NAMES = tuple(n for n, _ in _MOVES)
_WEIGHTS = tuple(w for _, w in _MOVES)


class StreamProgramGenerator:
    """Seeded programs for one worker: the same seed, the same programs."""

    def __init__(self, seed: int, worker: int = 0) -> None:
        self.rng = random.Random(f"mcp-fuzz/nsqd-stateful/{seed}/{worker}")

    def program(self) -> list[Op]:
        rng = self.rng
        ops = [Op("open", 0)]
        slots: dict[str, int | None] = {"served": 0, "waiting": None}  # the model of the backend's clients

        def leave(slot: int) -> None:
            if slot == slots["served"]:
                slots["served"], slots["waiting"] = slots["waiting"], None
            elif slot == slots["waiting"]:
                slots["waiting"] = None

        def reopen(slot: int) -> None:  # a new connection in ``slot``, then a command on it
            ops.extend((Op("open", slot), cmd(slot)))
            slots["served" if slots["served"] is None else "waiting"] = slot

        def cmd(slot: int) -> Op:
            name = rng.choice(COMMANDS)
            return Op("cmd", slot, (Write(command_bytes(name)),), name, valid=True)

        for _ in range(rng.randint(2, STEPS)):
            name = rng.choices(_NAMES, _WEIGHTS)[0]
            served, waiting = slots["served"], slots["waiting"]
            assert served is not None
            slot = served if waiting is None or rng.random() < 0.8 else waiting
            if name == "mutated":
                case = draw_case(rng)
                ops.append(Op("send", slot, case.writes, case.kind, case.valid, case.probe, note=case.note))
                if case.writes and case.writes[-1].end:  # the client left, maybe mid-frame
                    leave(slot)
                    reopen(slot)
            elif name == "second" and waiting is None:
                slots["waiting"] = 1 - served
                ops.append(Op("open", 1 - served))
            elif name == "close" and waiting is not None:
                ops.append(Op("close", slot, how=rng.choice(("fin", "rst"))))
                leave(slot)
            elif name in ("cut", "reconnect"):
                if name == "cut":
                    msg = rng.choice(CLIENT_MSGS)
                    whole = command_bytes(msg)
                    cut, how = rng.randint(1, len(whole) - 1), rng.choice(("fin", "rst"))
                    ops.append(Op("send", slot, (Write(whole[:cut], end=how),), f"{how}-mid-frame", in_sync=False,
                                  note=f"{msg} cut at {cut} by {how.upper()}"))
                leave(slot)  # a reconnect: the old connection closed, a new one in its slot
                reopen(slot)
            else:
                ops.append(cmd(slot))
        if rng.random() < 0.8 and slots["served"] is not None:
            ops.append(cmd(slots["served"]))
        return ops


def dumps(ops: list[Op]) -> bytes:
    """A program for the example database (``--db``)."""
    return json.dumps([op.to_json() for op in ops], separators=(",", ":")).encode()


def loads(data: bytes) -> list[Op] | None:
    """A program from the example database; None for anything else stored there."""
    try:
        return [Op.from_json(d) for d in json.loads(data)]
    except (ValueError, TypeError, KeyError):
        return None


def tried_kind(op: Op) -> str:
    """An op's row of ``summary.json``'s ``tried`` (and the live table): a mutated case's kind,
    ``valid`` for a command, ``connect`` or ``close`` for an op that sends no bytes (its one
    count under ``-``, no message id: ``message_names``). Every op played is a case
    (``EngineStats.cases``), so every one is in the table: a campaign starved of CPU, its
    stateless turn spent starting the backend, ran 256 ops of which the table held 198."""
    if op.what == "cmd":
        return "valid"
    return op.kind if op.what == "send" else {"open": "connect"}.get(op.what, op.what)


class StreamStatefulEngine:
    """Plays pipelined programs (``fuzz.nsqd_programs``) until the budget is spent: saved
    ones first (``--db``), then drawn ones; each failure goes to ``triage.add_program``
    (triage by careful replays, dedup, finding-N/), and a confirmed one is saved."""

    def __init__(self, triage: Any, db: str | None = None, worker: int = 0) -> None:
        self.triage = triage
        self.stats = EngineStats()
        self.database = open_database(db)
        self.worker = worker
        self.programs = 0
        self.generator = StreamProgramGenerator(triage.seed, worker)

    def _saved(self) -> list[list[Op]]:
        if self.database is None:
            return []
        return [ops for ops in (loads(v) for v in self.database.fetch(DB_KEY)) if ops]

    def _save(self, found: int) -> None:
        """A finding this program added: its minimised program, for the workers to come."""
        new = self.triage.findings[found:]
        if self.database is not None and new and new[-1].program:
            self.database.save(DB_KEY, json.dumps(new[-1].program, separators=(",", ":")).encode())

    def run(self, deadline: float, max_cases: int | None, tick: Callable[[EngineStats], None] | None,
            stop: Callable[[], bool]) -> EngineStats:
        """Fuzz until ``deadline``, ``max_cases`` ops played or ``stop()``; the backend now
        fuzzed, maybe a fresh one, is the triage's ``current``."""
        c, st = self.triage, self.stats
        b = c.current
        saved, spare = self._saved(), None
        gap = float(NSQD.params["update_gap_max_s"])
        clock = FuzzClock(st, tick)  # the live figures every TICK_S, a program's triage not fuzzing time

        def out_of_budget() -> bool:
            return st.spent(deadline, max_cases, stop)

        try:
            while not out_of_budget():
                ops = saved.pop(0) if saved else self.generator.program()
                if spare is None and (b.session.death() is not None or not b.session.live(gap)):
                    b = c.current = b.fresh()
                    c.target.count_restart("died")
                player = Player(b, fast=True, spare=spare)
                spare, hit, played = None, None, []
                try:
                    for op in ops:
                        if out_of_budget():
                            break
                        played.append(op)
                        clock.case(tried_kind(op), message_names(b"".join(w.data for w in op.writes)), mutation=False)
                        player.play(op)
                    else:
                        spare = player.finish()
                except Hit as h:
                    hit = h
                finally:
                    player.close() if spare is None else None
                self.programs += 1
                st.batches += 1
                if hit is not None:
                    with clock.triage():  # its own triage time
                        found = len(c.findings)
                        b = c.current = c.add_program(b, hit, played)
                        self._save(found)
        finally:
            clock.stop()
            if spare is not None:
                spare.close()
                with contextlib.suppress(ValueError):
                    b.session.conns.remove(spare)
        if tick is not None:
            tick(st)
        return st
