"""MAVLink's fuzz oracles (``mcp-fuzz --protocol mavlink``, issue 39 item 4): what a hit
showed (:class:`Signature`: the oracle, the rule it names, what it is about) and the answer
oracle (:func:`judge`): an answer a case must get (a COMMAND_ACK of its command, with
MAV_RESULT_UNSUPPORTED for an unknown one; a PARAM_VALUE of its name or index; a message of
a handshake) does not come before the probe's answer, nor within its bound
(``command_ack_max_s`` / ``param_reply_max_s``), or one it must not get comes (an ACK for a
command to another system, or of a frame with a bad checksum; a PARAM_VALUE naming a
parameter that does not exist), or two final COMMAND_ACKs answer one command (MAV-CMD-3).
The deaths (``crash``, ``hang``, ``unanswered``) are observed on the link by
``fuzz.mavlink_vehicle``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from mcp_conform.fuzz.mavlink_cases import Case, D, Expect, name_key, raw_fields

__all__ = ["FINAL", "Hit", "Signature", "answers", "judge"]

FINAL = frozenset(r for r in D.enums["MAV_RESULT"] if r != D.MAV_RESULT_IN_PROGRESS)


@dataclass(frozen=True)
class Signature:
    """What a hit showed: the oracle (crash, hang, unanswered, answer), the rule it names and
    what it is about (the case's kind, or for an answer what was wrong with it)."""

    oracle: str
    rule: str
    kind: str

    def describe(self) -> str:
        return f"{self.oracle}: {self.kind} ({self.rule})"

    def same(self, other: Signature) -> bool:
        """A replay shows this hit: the same oracle (an answer: also the same rule and what
        was wrong; a death is named by the case that makes it once that is known)."""
        return self.oracle == other.oracle and (self.oracle != "answer" or (self.rule, self.kind) == (
            other.rule, other.kind))


@dataclass(frozen=True)
class Hit:
    signature: Signature
    expected: str
    actual: str
    evidence: tuple[str, ...] = ()


def answers(e: Expect, frames: list[Any]) -> list[Any]:
    """The frames of ``frames`` that answer ``e`` (or break it, for a ``no-`` one)."""
    if e.what in ("ack", "no-ack"):
        return [m for m in frames if m.get_type() == "COMMAND_ACK" and m.command == e.key]
    if e.what == "msg":
        return [m for m in frames if m.get_type() in str(e.key).split("|")]
    if e.what == "param-index":
        return [m for m in frames if m.get_type() == "PARAM_VALUE" and raw_fields(m)["param_index"] == e.key]
    key = bytes.fromhex(str(e.key))
    return [m for m in frames if m.get_type() == "PARAM_VALUE" and name_key(raw_fields(m)["param_id"]) == key]


def judge(case: Case, e: Expect, frames: list[Any], late: Callable[[], bool], late_s: float) -> Hit | None:
    """``e`` of ``case`` judged over the vehicle's ``frames`` before the probe's answer; an
    answer missing there may come ``late()`` (within ``late_s``: a vehicle that defers it,
    as ArduPilot queues some answers)."""
    got = answers(e, frames)
    what = _expected(e)
    where = f"in answer to {case.describe()}"
    if e.what.startswith("no-"):
        if got:
            return Hit(Signature("answer", e.rule, f"{e.what} broken by {case.kind}"), f"{what} {where}",
                       f"the vehicle answered: {_show(got[0])}")
        return None
    if not got:
        if late():
            return None
        others = [m for m in frames if m.get_type() == "COMMAND_ACK"] if e.what == "ack" else []
        actual = (f"only a COMMAND_ACK for another command: {_show(others[0])}" if others
                  else f"no answer before the probe's PARAM_VALUE, nor within {late_s:g} s")
        return Hit(Signature("answer", e.rule, f"{e.what} missing after {case.kind}"), f"{what} {where}", actual)
    if e.what == "ack":
        finals = [m for m in got if m.result in FINAL]
        if len(finals) > 1:
            return Hit(Signature("answer", "MAV-CMD-3", f"two final acks after {case.kind}"),
                       f"one final COMMAND_ACK {where}", f"{len(finals)}: " + "; ".join(_show(m) for m in finals))
        if e.result is not None and not any(m.result == e.result for m in got):
            return Hit(Signature("answer", e.rule, f"ack result after {case.kind}"),
                       f"{what} with result {_result(e.result)} {where}", f"result {_result(got[0].result)}")
    return None


def _expected(e: Expect) -> str:
    if e.what in ("ack", "no-ack"):
        return f"{'no ' if e.what == 'no-ack' else 'a '}COMMAND_ACK of command {e.key}"
    if e.what == "param-index":
        return f"the PARAM_VALUE of index {e.key}"
    if e.what == "msg":
        return "a " + str(e.key).replace("|", " or ")
    return f"{'no' if e.what == 'no-param' else 'a'} PARAM_VALUE of {_name(e.key)}"


def _name(key: Any) -> str:
    return repr(bytes.fromhex(str(key)))


def _result(r: int) -> str:
    entry = D.enums["MAV_RESULT"].get(r)
    return f"{entry.name} ({r})" if entry is not None else str(r)


def _show(m: Any) -> str:
    fields = {k: v for k, v in m.to_dict().items() if k != "mavpackettype"}
    return f"{m.get_type()} {fields}"
