"""The stateful engine's programs: what a manager (and a confused network) does to a drone
across a mission, drawn by a seeded ``random.Random`` (issue 36 item 4).

A program is a list of :class:`Move`\\ s, each a manager's action with its arguments fixed
when drawn: a command of any kind sent 1-3 times (every copy ACKed, MCP-ACK-1; delivered
once, MCP-DUP-1/2), the last command again (a duplicate), a late copy of an older one
(MCP-DUP-4), a broadcast (MCP-ACK-4), a unicast to another ID (MCP-ACK-5), a command from
another source (MCP-DUP-3), an ACK to the node (MCP-ACK-6), the sequence number jumped to
just before 65535 so the next commands wrap to 0 (MCP-SEQ-3), a malformed datagram of any
kind of ``spec.generators`` (MCP-ROB-*), End_Mission as a program's last move, and a fresh
node whose Mission_Ready ACKs are withheld as its first (MCP-RTX-1/2, MCP-SEQ-2). Commands
come in any order: a node is sent WP_On before any WP_List, Start_Mission twice, and so on.

Moves are drawn by plain ``random`` calls (microseconds each), not by hypothesis's engine:
hypothesis's rule-based machine cost about 1 ms per step on the 2-core test host, a ceiling
of about 1,000 steps per second before a single datagram was sent. A program is rendered
to datagrams only when played (the sequence numbers are the driver's at that time), so a
program saved in the example database replays on any worker. ``Move.describe`` prints a
program as a finding shows it.
"""

from __future__ import annotations

import json
import random
from dataclasses import asdict, dataclass

from mcp_conform.spec.codec import Action
from mcp_conform.spec.generators import MALFORMED_KINDS

__all__ = ["COMMANDS", "Move", "ProgramGenerator", "dumps", "loads", "program_text"]

COMMANDS = (Action.START_MISSION, Action.WP_LIST, Action.WP_ON, Action.WP_OFF,
            Action.OBSTACLES_LIST, Action.MAV_PASSTHROUGH)
#: How a command's action is drawn: Mav_Passthrough three times as often as each other one
#: (its frames are what the vehicle's record shows, for the duplicate and wrap rules).
_COMMAND_WEIGHTS = tuple(3 if a == Action.MAV_PASSTHROUGH else 1 for a in COMMANDS)
STEPS = 24  # moves per program at most
#: (move, weight) of the moves inside a program
_MOVES = (("command", 8), ("duplicate", 3), ("late_copy", 2), ("broadcast", 1), ("to_other_id", 1),
          ("other_source", 1), ("ack_to_node", 1), ("near_wrap", 2), ("garbage", 2))
_NAMES = tuple(n for n, _ in _MOVES)
_WEIGHTS = tuple(w for _, w in _MOVES)
#: One program in this many starts a fresh node with Mission_Ready's ACK withheld, one in
#: this many ends with End_Mission: each costs a node's restart (0.3-1 s, as many cases as
#: a second of fuzzing), so they stay rare.
RESTART_ODDS = 1000
_KINDS = tuple(MALFORMED_KINDS)


@dataclass(frozen=True)
class Move:
    """One manager's move; ``name`` says which, the rest are its arguments."""

    name: str
    action: int = 0  # command, broadcast, to_other_id, other_source
    copies: int = 1  # command: copies sent; withhold: copies of Mission_Ready left unACKed
    arg: int = 0  # late_copy: how far back; to_other_id: ID offset; ack_to_node: the seq named;
    #               near_wrap: how far before 65535; garbage: the malformed kind's index
    seed: int = 0  # the payload's (items, malformed bytes) seeded draw

    def describe(self) -> str:
        name = Action(self.action).name if self.name in ("command", "broadcast", "to_other_id",
                                                          "other_source") else ""
        if self.name == "command":
            return f"command({name}, copies={self.copies})"
        if self.name in ("broadcast", "other_source"):
            return f"{self.name}({name})"
        if self.name == "to_other_id":
            return f"to_other_id({name}, offset={self.arg})"
        if self.name == "late_copy":
            return f"late_copy(back={self.arg})"
        if self.name == "ack_to_node":
            return f"ack_to_node(seq={self.arg})"
        if self.name == "near_wrap":
            return f"near_wrap(seq={0xFFFF - self.arg})"
        if self.name == "garbage":
            return f"garbage({_KINDS[self.arg % len(_KINDS)]})"
        if self.name == "withhold":
            return f"restart_withholding_acks(copies={self.copies})"
        return f"{self.name}()"

    @property
    def kind(self) -> str:
        """The malformed kind of a ``garbage`` move."""
        return _KINDS[self.arg % len(_KINDS)]


class ProgramGenerator:
    """Seeded programs for one worker: the same seed, the same programs."""

    def __init__(self, seed: int, worker: int = 0, *, restarts: bool = True) -> None:
        self.rng = random.Random(f"mcp-fuzz/stateful/{seed}/{worker}")
        self.restarts = restarts  # spawn mode: a program may end the node's mission or restart it

    def program(self) -> list[Move]:
        rng = self.rng
        moves: list[Move] = []
        if self.restarts and rng.randrange(RESTART_ODDS) == 0:
            moves.append(Move("withhold", copies=rng.randint(1, 3)))
        history = 0
        wrapped = False
        for _ in range(rng.randint(3, STEPS)):
            name = rng.choices(_NAMES, _WEIGHTS)[0]
            if name in ("duplicate", "late_copy") and history < (1 if name == "duplicate" else 2):
                name = "command"
            if name == "near_wrap" and wrapped:
                name = "command"
            if name == "command":
                history += 1
                moves.append(Move(name, int(rng.choices(COMMANDS, _COMMAND_WEIGHTS)[0]),
                                  copies=rng.choice((1, 1, 2, 3)), seed=rng.getrandbits(32)))
            elif name in ("broadcast", "other_source"):
                moves.append(Move(name, int(rng.choice(COMMANDS)), seed=rng.getrandbits(32)))
            elif name == "to_other_id":
                moves.append(Move(name, int(rng.choice(COMMANDS)), arg=rng.randint(1, 3), seed=rng.getrandbits(32)))
            elif name == "late_copy":
                moves.append(Move(name, arg=rng.randint(2, 4)))
            elif name == "ack_to_node":
                moves.append(Move(name, arg=rng.getrandbits(16)))
            elif name == "near_wrap":
                # once per program, so no number is used for two messages (MCP-SEQ-3: 0
                # after 65535 is new)
                wrapped = True
                moves.append(Move(name, arg=rng.randint(0, 2)))
            elif name == "garbage":
                moves.append(Move(name, arg=rng.randrange(len(_KINDS)), seed=rng.getrandbits(32)))
            else:
                moves.append(Move(name))
        if self.restarts and history >= 2 and rng.randrange(RESTART_ODDS) == 0:
            moves.append(Move("end_mission"))
        return moves


def program_text(moves: list[Move]) -> str:
    """A program as a finding prints it, one move a line."""
    return "\n".join(m.describe() for m in moves)


def dumps(moves: list[Move]) -> bytes:
    """A program for the example database (``--db``)."""
    return json.dumps([asdict(m) for m in moves], separators=(",", ":")).encode()


def loads(data: bytes) -> list[Move] | None:
    """A program from the example database; None for anything else stored there."""
    try:
        return [Move(**d) for d in json.loads(data)]
    except (ValueError, TypeError):
        return None
