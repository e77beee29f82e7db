"""The faulty ground stations of ``--protocol mavlink --role gcs`` (issue 39's matrix; issue 38,
item 3: its faults as models): the reference GCS (``reference_impl.mavlink_gcs.ReferenceGcs``)
with one hook changed, each breaking one rule of ``spec/mavlink.yaml``. The same classes run as
processes (``tests/mavlink/faulty_gcs.py``, the real-socket smoke runs) and in the simulator
(:mod:`sim.gcs`, on the virtual clock), so a fault is one definition, and what it breaks is
declared on it (:class:`Breaks`: its rule, and the SHOULD rules it breaks besides by its
nature); ``RULES`` and ``BROKEN`` are read from those declarations.

- ``no-heartbeat``: no HEARTBEAT at all (MAV-HB-2);
- ``type-quadrotor``: HEARTBEAT.type MAV_TYPE_QUADROTOR (MAV-HB-4);
- ``mavlink1-start``: pymavlink as it comes, starting in MAVLink 1 and switching on the
  vehicle's first MAVLink 2 frame, its sequence numbers starting again at 0 (MAV-HB-11);
- ``items-out-of-order``: the first request for item 1 answered with item 2 (MAV-MIS-20);
- ``degrees``: the mission's latitude and longitude in degrees, not degE7, as seed 001 sends
  them (MAV-MIS-26);
- ``degE7-in-float-item``: the items as the deprecated MISSION_ITEM with the degE7 integers in
  its degrees fields, the defect of seed 001's ``mavlink_send_take_off`` (MAV-MIS-26; the
  deprecated message is MAV-MIS-12's too, a SHOULD: ``Breaks.also``);
- ``no-count-resend``: an unanswered MISSION_COUNT never resent (MAV-MIS-22);
- ``mission-never-gives-up``: an unanswered MISSION_COUNT resent 50 times (MAV-MIS-23);
- ``ignores-error-ack``: an error MISSION_ACK does not end the upload (MAV-MIS-24);
- ``no-command-resend``: a command never resent (MAV-CMD-6);
- ``command-never-gives-up``: a command resent 50 times (MAV-CMD-9);
- ``confirmation-not-incremented``: every transmission with confirmation 0 (MAV-CMD-8, SHOULD);
- ``ignores-in-progress``: MAV_RESULT_IN_PROGRESS taken as no answer: resent (MAV-CMD-10, SHOULD);
- ``accepts-any-ack``: a COMMAND_ACK of any command taken as the answer (MAV-CMD-17);
- ``no-param-resend``: a PARAM_SET never resent (MAV-PRM-16, SHOULD);
- ``relists-on-gap``: a list with indices missing asked for whole again (MAV-PRM-14, SHOULD);
- ``rereads-out-of-order``: every parameter that came out of order read again by index (MAV-PRM-15).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from mcp_conform.reference_impl.mavlink_gcs import ReferenceGcs, mav

__all__ = ["BROKEN", "FAULTS", "RULES", "Breaks", "Fault"]


@dataclass(frozen=True)
class Breaks:
    """What a fault breaks: ``rule``, the one of its fault (failed, or warned for a SHOULD; the
    case that judges it names it), and ``also``, SHOULD rules it breaks besides by what it is
    (warned, never failed: the deprecated MISSION_ITEM of ``degE7-in-float-item`` is
    MAV-MIS-12's)."""

    rule: str
    also: tuple[str, ...] = ()

    @property
    def rules(self) -> frozenset[str]:
        """Every rule a run against the fault fails or warns, and no other."""
        return frozenset({self.rule, *self.also})


class Fault(ReferenceGcs):
    """The reference ground station with one hook changed; ``breaks`` says what that breaks."""

    breaks: ClassVar[Breaks]


class NoHeartbeat(Fault):
    breaks = Breaks("MAV-HB-2")

    def heartbeat(self) -> Any | None:
        return None


class TypeQuadrotor(Fault):
    breaks = Breaks("MAV-HB-4")

    def heartbeat(self) -> Any | None:
        hb = super().heartbeat()
        if hb is not None:
            hb.type = mav.MAV_TYPE_QUADROTOR
        return hb


class Mavlink1Start(Fault):
    breaks = Breaks("MAV-HB-11")
    mavlink2_first = False  # pymavlink's default: MAVLink 1 until it hears 2


class ItemsOutOfOrder(Fault):
    breaks = Breaks("MAV-MIS-20")
    swapped = False

    def item_for(self, seq: int, items: list[Any]) -> Any:
        if seq == 1 and len(items) > 2 and not self.swapped:
            self.swapped = True
            return items[2]
        return items[seq]


class Degrees(Fault):
    breaks = Breaks("MAV-MIS-26")

    def plan(self, path: str | None) -> list[Any]:
        items = super().plan(path)
        for item in items:
            item.x, item.y = round(item.x / 1e7), round(item.y / 1e7)
        return items


class DegE7InFloatItem(Fault):
    breaks = Breaks("MAV-MIS-26", also=("MAV-MIS-12",))

    def plan(self, path: str | None) -> list[Any]:
        return [self.encode("MISSION_ITEM", seq=i.seq, frame=i.frame, command=i.command, current=0, autocontinue=1,
                            param1=i.param1, param2=i.param2, param3=i.param3, param4=i.param4, x=float(i.x),
                            y=float(i.y), z=i.z, mission_type=i.mission_type)
                for i in super().plan(path)]


class NoCountResend(Fault):
    breaks = Breaks("MAV-MIS-22")
    mission_retries = 0


class MissionNeverGivesUp(Fault):
    breaks = Breaks("MAV-MIS-23")
    mission_retries = 50


class IgnoresErrorAck(Fault):
    breaks = Breaks("MAV-MIS-24")

    def ends_upload(self, ack: Any) -> bool:
        return bool(ack.type == mav.MAV_MISSION_ACCEPTED)


class NoCommandResend(Fault):
    breaks = Breaks("MAV-CMD-6")
    command_retries = 0


class CommandNeverGivesUp(Fault):
    breaks = Breaks("MAV-CMD-9")
    command_retries = 50


class ConfirmationNotIncremented(Fault):
    breaks = Breaks("MAV-CMD-8")

    def confirmation(self, transmission: int) -> int:
        return 0


class IgnoresInProgress(Fault):
    breaks = Breaks("MAV-CMD-10")

    def answers(self, ack: Any, command: int) -> bool:
        return bool(ack.command == command and ack.result != mav.MAV_RESULT_IN_PROGRESS)


class AcceptsAnyAck(Fault):
    breaks = Breaks("MAV-CMD-17")

    def answers(self, ack: Any, command: int) -> bool:
        return True


class NoParamResend(Fault):
    breaks = Breaks("MAV-PRM-16")
    param_retries = 0


class RelistsOnGap(Fault):
    breaks = Breaks("MAV-PRM-14")

    def to_read(self, got: dict[int, Any], count: int, order: list[int]) -> list[int]:
        if len(got) < count:  # the whole list again, not the missing ones
            self.send(self.encode("PARAM_REQUEST_LIST"))
            for _ in range(4 * count):
                if (msg := self.recv(["PARAM_VALUE"], self.param_timeout)) is None:
                    break
                got.setdefault(msg.param_index, msg)
        return []


class RereadsOutOfOrder(Fault):
    breaks = Breaks("MAV-PRM-15")

    def to_read(self, got: dict[int, Any], count: int, order: list[int]) -> list[int]:
        late = {b for a, b in zip(order, order[1:], strict=False) if b != a + 1}  # a list taken as ordered
        return sorted(late | (set(range(count)) - set(got)))


#: each fault's ground station (``none``: the reference itself)
FAULTS: dict[str, type[ReferenceGcs]] = {
    "none": ReferenceGcs, "no-heartbeat": NoHeartbeat, "type-quadrotor": TypeQuadrotor,
    "mavlink1-start": Mavlink1Start, "items-out-of-order": ItemsOutOfOrder, "degrees": Degrees,
    "degE7-in-float-item": DegE7InFloatItem, "no-count-resend": NoCountResend, "mission-never-gives-up": MissionNeverGivesUp,
    "ignores-error-ack": IgnoresErrorAck, "no-command-resend": NoCommandResend,
    "command-never-gives-up": CommandNeverGivesUp, "confirmation-not-incremented": ConfirmationNotIncremented,
    "ignores-in-progress": IgnoresInProgress, "accepts-any-ack": AcceptsAnyAck, "no-param-resend": NoParamResend,
    "relists-on-gap": RelistsOnGap, "rereads-out-of-order": RereadsOutOfOrder,
}
_FAULTY: dict[str, type[Fault]] = {n: c for n, c in FAULTS.items() if issubclass(c, Fault)}
#: the rule each fault breaks (its ``Breaks.rule``; a SHOULD rule's is warned)
RULES: dict[str, str] = {n: c.breaks.rule for n, c in _FAULTY.items()}
#: every rule a run against each fault fails or warns, and no other (its ``Breaks.rules``)
BROKEN: dict[str, frozenset[str]] = {n: c.breaks.rules for n, c in _FAULTY.items()}
