"""MAVLink's fuzz oracles (``mcp-fuzz --protocol mavlink``, issue 39 item 4): what a hit
showed (:class:`Signature`: the oracle, the rule it names, what it is about) and the answer
oracle (:func:`judge`): an answer a case must get (a COMMAND_ACK of its command, with
MAV_RESULT_UNSUPPORTED for an unknown one; a PARAM_VALUE of its name or index; a message of
a handshake) does not come before the probe's answer, nor within its bound
(``command_ack_max_s`` / ``param_reply_max_s``), or one it must not get comes (an ACK for a
command to another system, or of a frame with a bad checksum; a PARAM_VALUE naming a
parameter that does not exist), or two final COMMAND_ACKs answer one command (MAV-CMD-3).
The deaths are judged here too, over what ``fuzz.mavlink_vehicle`` observes on its link
(:class:`Observed`): the probe behind a case unanswered within ``param_reply_max_s`` is a
``crash`` (the process exited or the link closed), a ``hang`` (the vehicle's HEARTBEAT stopped
for ``heartbeat_gap_max_s``: MAV-HB-1) or ``unanswered`` (it beats on and no longer answers:
MAV-PRM-4 / MAV-HB-14), each named by the case's rule (:func:`lost`); a HEARTBEAT that stops
while the vehicle answers is a ``hang`` too (:func:`lost`, :func:`silent`, :func:`beats_on`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any, Protocol

from mcp_conform.fuzz.mavlink_cases import Case, D, Expect, name_key, raw_fields
from mcp_conform.spec import MAVLINK

__all__ = ["FINAL", "Hit", "Observed", "Signature", "answers", "beats_on", "judge", "judge_case", "lost", "silent"]

FINAL = frozenset(r for r in D.enums["MAV_RESULT"] if r != D.MAV_RESULT_IN_PROGRESS)
REPLY_S = float(MAVLINK.params["param_reply_max_s"])
GAP_S = float(MAVLINK.params["heartbeat_gap_max_s"])


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


class Observed(Protocol):
    """What the oracles of a vehicle's death read of it (``fuzz.mavlink_vehicle.MavVehicle``)."""

    last_beat: float

    @property
    def probe_name(self) -> str: ...
    def alive(self) -> bool: ...
    def ending(self, grace: float = 0.0) -> tuple[str | None, tuple[str, ...]]: ...
    def wait_beat(self, since: float) -> bool: ...
    def probe_answered(self, timeout: float) -> bool: ...


def _hang(rule: str, kind: str, actual: str) -> Hit:
    return Hit(Signature("hang", rule, kind), f"a HEARTBEAT at least every {GAP_S:g} s (MAV-HB-1)", actual)


def lost(v: Observed, case: Case, answered: bool = False) -> Hit | None:
    """The probe behind ``case`` went unanswered (``answered``: it was, but the HEARTBEAT is
    late): dead (``crash``), hung (``hang``), deaf (``unanswered``), or late only (None)."""
    sent = time.monotonic()
    what = f"after {case.describe()}"
    if not v.alive() or (not answered and not v.wait_beat(sent)):
        if not v.alive():
            how, ev = v.ending(1.0)  # a closed link: the process's exit, when it is exiting
            how = how or "the vehicle closed the link"
            return Hit(Signature("crash", case.rule, case.kind), "the vehicle goes on", f"{how} {what}", ev)
        return _hang(case.rule, case.kind, f"no HEARTBEAT for {time.monotonic() - v.last_beat:.1f} s {what}")
    if answered:
        if v.wait_beat(sent):
            return None
        return _hang(case.rule, case.kind,
                     f"no HEARTBEAT for {time.monotonic() - v.last_beat:.1f} s {what} (it still answers)")
    if v.probe_answered(0.0):
        return None  # late, not lost (a loaded host)
    return Hit(Signature("unanswered", case.rule, case.kind),
               f"PARAM_REQUEST_READ of {v.probe_name} answered within {REPLY_S:g} s (MAV-PRM-4), as before the case",
               f"no PARAM_VALUE {what}; its HEARTBEAT goes on")


def silent(v: Observed, since: float) -> Hit | None:
    """After a replay: a HEARTBEAT after ``since`` (nothing), or the gap past its bound (MAV-HB-1)."""
    if v.wait_beat(since):
        return None
    return _hang("MAV-HB-1", "", f"no HEARTBEAT for {time.monotonic() - v.last_beat:.1f} s after the replay")


def beats_on(v: Observed) -> Hit | None:
    """With nothing sent (the baseline of a stopped heartbeat; what the link held read
    first): the next two HEARTBEATs each within ``heartbeat_gap_max_s``, or a hang."""
    for which in ("first", "second"):
        t0 = v.last_beat = time.monotonic()
        if not v.wait_beat(t0):
            return _hang("MAV-HB-1", "", f"no {which} HEARTBEAT within {GAP_S:g} s with nothing sent")
    return None


def judge_case(case: Case, frames: list[Any], late: Callable[[Expect, float], bool],
               late_s: Callable[[Expect], float]) -> Hit | None:
    """Each expectation of ``case`` judged over the vehicle's ``frames`` before the probe's
    answer (:func:`judge`): the first broken, or None; an answer missing there may come
    ``late(e, late_s(e))``."""
    for e in case.expect:
        hit = judge(case, e, frames, partial(late, e, late_s(e)), late_s(e))
        if hit is not None:
            return hit
    return None


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
