"""The MAVLink monitor's numbering of a ground station's COMMAND_LONGs (judge._mavlink_link,
``CommandService._numbering``): confirmation 0 on a command's first transmission (MAV-CMD-7),
the last one's + 1 on a resend (MAV-CMD-8), when a resend crossed the COMMAND_ACK that
answered the transmission before it.

The gcs role's simulator found it (tests/sim/test_mavlink_gcs_sim.py, seed 6 on a lossy link
with the runner late by up to 1 s): the ground station resent its command (confirmation 1)
while the ACK of the first transmission was on the way; the ACK had taken the first one off
the monitor's queue, and the resend was judged a new command's first transmission -- a false
MAV-CMD-7 on the reference GCS.
"""

from __future__ import annotations

import pytest

from mcp_conform.judge.mavlink_monitor import MavlinkMonitor
from mcp_conform.spec import MAVLINK
from mcp_conform.traceio.mavlink import MavFrame

MAV = MAVLINK.dialect
VEHICLE, GCS = (1, 1), (255, 190)
WINDOW = float(MAVLINK.params["command_resend_window_s"])


def _command(conf: int) -> tuple[tuple[int, int], str, dict]:
    return GCS, "COMMAND_LONG", {"target_system": 1, "target_component": 1, "command": MAV.MAV_CMD_DO_SET_MODE,
                                 "confirmation": conf, "param1": 1, "param2": 4, "param3": 0, "param4": 0,
                                 "param5": 0, "param6": 0, "param7": 0}


ACK = (VEHICLE, "COMMAND_ACK", {"command": MAV.MAV_CMD_DO_SET_MODE, "result": MAV.MAV_RESULT_ACCEPTED, "progress": 0,
                                "result_param2": 0, "target_system": 255, "target_component": 190})


def _judge(*items: tuple[float, tuple[tuple[int, int], str, dict]]) -> dict[str, str]:
    """The gcs role's verdicts on a trace of heartbeats and ``items`` (time s, frame), each
    frame packed by pymavlink's dialect and recorded from the vehicle's side as our captures do."""
    vehicle = {"type": MAV.MAV_TYPE_QUADROTOR, "autopilot": MAV.MAV_AUTOPILOT_ARDUPILOTMEGA, "base_mode": 0,
               "custom_mode": 0, "system_status": MAV.MAV_STATE_STANDBY}
    gcs = {**vehicle, "type": MAV.MAV_TYPE_GCS, "autopilot": MAV.MAV_AUTOPILOT_INVALID}
    end = int(max(t for t, _ in items)) + 2
    beats = [x for s in range(end) for x in ((float(s), (VEHICLE, "HEARTBEAT", vehicle)),
                                             (s + 0.5, (GCS, "HEARTBEAT", gcs)))]
    coders: dict[tuple[int, int], object] = {}
    mon = MavlinkMonitor(roles=("gcs",), complete=True)
    for t, (src, name, fields) in sorted([*beats, *items], key=lambda x: x[0]):
        enc = coders.setdefault(src, MAV.MAVLink(None, srcSystem=src[0], srcComponent=src[1]))
        msg = getattr(enc, name.lower() + "_encode")(**fields)
        raw = bytes(msg.pack(enc))
        enc.seq = (enc.seq + 1) % 256  # type: ignore[attr-defined]
        mon.feed(MavFrame(mon.count, int(t * 1e9), "rx" if src == GCS else "tx", raw, MAV.MAVLink(None).parse_char(raw)))
    mon.finish()
    return mon.verdicts()


def test_a_resend_that_crossed_the_ack_is_a_resend():
    """Sent 0.3 s after the first, before the ground station read the ACK that came 0.1 s after
    it (the vehicle answers the resend too): a resend, numbered right. Failed MAV-CMD-7 before."""
    v = _judge((2.0, _command(0)), (2.1, ACK), (2.3, _command(1)), (2.35, ACK))
    assert v["MAV-CMD-7"] == "passed" and v["MAV-CMD-8"] == "passed", v


def test_a_crossed_resend_misnumbered_is_judged_by_neither_rule():
    """confirmation 3 after 0: a resend misnumbered or a new command misnumbered, the trace
    cannot tell which -- neither rule fails on it (the runner's cases judge both where the
    runner withholds the ACK: tests/sim's confirmation-not-incremented)."""
    v = _judge((2.0, _command(0)), (2.1, ACK), (2.3, _command(3)), (2.35, ACK))
    assert v["MAV-CMD-7"] == "passed" and v["MAV-CMD-8"] == "not_observed", v


@pytest.mark.parametrize("later", [WINDOW + 0.5, 2 * WINDOW])
def test_a_command_long_after_its_ack_with_confirmation_1_is_a_first_one_misnumbered(later):
    """The same command with confirmation 1 past the resend window after the ACK: no resend of
    the acknowledged one, a new command's first transmission: MAV-CMD-7 fails."""
    v = _judge((2.0, _command(0)), (2.1, ACK), (2.1 + later, _command(1)), (2.2 + later, ACK))
    assert v["MAV-CMD-7"] == "failed", v


def test_a_new_command_after_the_ack_with_confirmation_0_is_a_first_one():
    v = _judge((2.0, _command(0)), (2.1, ACK), (2.5, _command(0)), (2.6, ACK))
    assert v["MAV-CMD-7"] == "passed" and v["MAV-CMD-8"] == "not_observed", v


def test_a_first_transmission_with_confirmation_1_fails_cmd_7():
    v = _judge((2.0, _command(1)), (2.1, ACK))
    assert v["MAV-CMD-7"] == "failed", v


def test_a_resend_while_the_first_is_owed_its_ack_is_judged_for_its_number():
    """No ACK yet: the resend with confirmation 0 breaks MAV-CMD-8 (SHOULD: warned)."""
    v = _judge((2.0, _command(0)), (3.6, _command(0)), (3.7, ACK), (3.8, ACK))
    assert v["MAV-CMD-7"] == "passed" and v["MAV-CMD-8"] == "warned", v
