"""Faulty ground stations for the tests: the reference GCS (``reference_impl.mavlink_gcs``)
with one thing changed, so that ``mcp-conform --protocol mavlink --role gcs`` must fail exactly
the rule of that one thing.

    python tests/mavlink/faulty_gcs.py --fault NAME URL [reference GCS options]

Faults (the rule each breaks):

- none: the reference itself;
- no-heartbeat: no HEARTBEAT at all (MAV-HB-2);
- type-quadrotor: HEARTBEAT.type MAV_TYPE_QUADROTOR (MAV-HB-4);
- mavlink1-start: pymavlink as it comes, starting in MAVLink 1 and switching on the vehicle's
  first MAVLink 2 frame, its sequence numbers starting again at 0 (MAV-HB-11);
- items-out-of-order: the first request for item 1 answered with item 2 (MAV-MIS-20);
- degrees: the mission's latitude and longitude in degrees, not degE7, as seed 001 sends them
  (MAV-MIS-26);
- no-count-resend: an unanswered MISSION_COUNT never resent (MAV-MIS-22);
- mission-never-gives-up: an unanswered MISSION_COUNT resent 50 times (MAV-MIS-23);
- ignores-error-ack: an error MISSION_ACK does not end the upload (MAV-MIS-24);
- no-command-resend: a command never resent (MAV-CMD-6);
- command-never-gives-up: a command resent 50 times (MAV-CMD-9);
- confirmation-not-incremented: every transmission with confirmation 0 (MAV-CMD-8, SHOULD);
- ignores-in-progress: MAV_RESULT_IN_PROGRESS taken as no answer: resent (MAV-CMD-10, SHOULD);
- accepts-any-ack: a COMMAND_ACK of any command taken as the answer (MAV-CMD-17);
- no-param-resend: a PARAM_SET never resent (MAV-PRM-16, SHOULD);
- relists-on-gap: a list with indices missing asked for whole again (MAV-PRM-14, SHOULD);
- rereads-out-of-order: every parameter that came out of order read again by index (MAV-PRM-15).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run as a script from a checkout

from mcp_conform.reference_impl.mavlink_gcs import ReferenceGcs, main, mav  # noqa: E402


class NoHeartbeat(ReferenceGcs):
    def heartbeat(self) -> Any | None:
        return None


class TypeQuadrotor(ReferenceGcs):
    def heartbeat(self) -> Any | None:
        hb = super().heartbeat()
        hb.type = mav.MAV_TYPE_QUADROTOR
        return hb


class Mavlink1Start(ReferenceGcs):
    mavlink2_first = False  # pymavlink's default: MAVLink 1 until it hears 2


class ItemsOutOfOrder(ReferenceGcs):
    swapped = False

    def item_for(self, seq: int, items: list[Any]) -> Any:
        if seq == 1 and len(items) > 2 and not self.swapped:
            self.swapped = True
            return items[2]
        return items[seq]


class Degrees(ReferenceGcs):
    def plan(self, path: str | None) -> list[Any]:
        items = super().plan(path)
        for item in items:
            item.x, item.y = round(item.x / 1e7), round(item.y / 1e7)
        return items


class NoCountResend(ReferenceGcs):
    mission_retries = 0


class MissionNeverGivesUp(ReferenceGcs):
    mission_retries = 50


class IgnoresErrorAck(ReferenceGcs):
    def ends_upload(self, ack: Any) -> bool:
        return bool(ack.type == mav.MAV_MISSION_ACCEPTED)


class NoCommandResend(ReferenceGcs):
    command_retries = 0


class CommandNeverGivesUp(ReferenceGcs):
    command_retries = 50


class ConfirmationNotIncremented(ReferenceGcs):
    def confirmation(self, transmission: int) -> int:
        return 0


class IgnoresInProgress(ReferenceGcs):
    def answers(self, ack: Any, command: int) -> bool:
        return bool(ack.command == command and ack.result != mav.MAV_RESULT_IN_PROGRESS)


class AcceptsAnyAck(ReferenceGcs):
    def answers(self, ack: Any, command: int) -> bool:
        return True


class NoParamResend(ReferenceGcs):
    param_retries = 0


class RelistsOnGap(ReferenceGcs):
    def to_read(self, got: dict[int, Any], count: int, order: list[int]) -> list[int]:
        if len(got) < count:  # the whole list again, not the missing ones
            self.send(self.encode("PARAM_REQUEST_LIST"))
            for _ in range(4 * count):
                if (msg := self.recv(["PARAM_VALUE"], self.param_timeout)) is None:
                    break
                got.setdefault(msg.param_index, msg)
        return []


class RereadsOutOfOrder(ReferenceGcs):
    def to_read(self, got: dict[int, Any], count: int, order: list[int]) -> list[int]:
        late = {b for a, b in zip(order, order[1:], strict=False) if b != a + 1}  # a list taken as ordered
        return sorted(late | (set(range(count)) - set(got)))


FAULTS: dict[str, type[ReferenceGcs]] = {
    "none": ReferenceGcs, "no-heartbeat": NoHeartbeat, "type-quadrotor": TypeQuadrotor,
    "mavlink1-start": Mavlink1Start, "items-out-of-order": ItemsOutOfOrder, "degrees": Degrees,
    "no-count-resend": NoCountResend, "mission-never-gives-up": MissionNeverGivesUp,
    "ignores-error-ack": IgnoresErrorAck, "no-command-resend": NoCommandResend,
    "command-never-gives-up": CommandNeverGivesUp, "confirmation-not-incremented": ConfirmationNotIncremented,
    "ignores-in-progress": IgnoresInProgress, "accepts-any-ack": AcceptsAnyAck, "no-param-resend": NoParamResend,
    "relists-on-gap": RelistsOnGap, "rereads-out-of-order": RereadsOutOfOrder,
}


if __name__ == "__main__":
    args = sys.argv[1:]
    if len(args) < 2 or args[0] != "--fault" or args[1] not in FAULTS:
        print(f"usage: faulty_gcs.py --fault {'|'.join(FAULTS)} URL [options]", file=sys.stderr)
        raise SystemExit(2)
    raise SystemExit(main(["gcs", *args[2:]], gcs_class=FAULTS[args[1]]))
