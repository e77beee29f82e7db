"""CMD — the command protocol (https://mavlink.io/en/services/command.html): COMMAND_LONG and
COMMAND_INT answered by one COMMAND_ACK naming the command, unknown commands UNSUPPORTED, a
retransmission (confirmation > 0) answered again, commands for other systems and components
left alone, a long-running command's progress and end. The command the runner sends is
MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: it changes nothing on a vehicle, and any MAV_RESULT
is an answer; the long-running one is the barometer's calibration, harmless on the ground."""

from __future__ import annotations

from mcp_conform.conformance.cases_mavlink.mavlink_services import UNKNOWN_COMMAND, result_name
from mcp_conform.conformance.marks import rules
from mcp_conform.harness.errors import Inconclusive
from mcp_conform.spec import MAVLINK

MAV = MAVLINK.dialect
PROBE = MAV.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES
#: the long-running command: MAV_CMD_PREFLIGHT_CALIBRATION with param3 1, the barometer's
#: ground-pressure calibration (ArduPilot's GCS_MAVLINK_InProgress answers it
#: MAV_RESULT_IN_PROGRESS while an airspeed sensor calibrates with it, GCS_Common.cpp)
CALIBRATION = MAV.MAV_CMD_PREFLIGHT_CALIBRATION
IN_PROGRESS = MAV.MAV_RESULT_IN_PROGRESS


def start_long_command(node):
    """The calibration sent; its send time once the vehicle answered it
    MAV_RESULT_IN_PROGRESS, else Inconclusive (the vehicle runs no command long enough to
    judge MAV-CMD-11..13)."""
    since = node.command_long(CALIBRATION, 0, 0, 1)
    node.link.wait_for(lambda: bool(node.acks(since, CALIBRATION)), node.ack_max)
    acks = node.acks(since, CALIBRATION)
    if not acks:
        raise Inconclusive("MAV_CMD_PREFLIGHT_CALIBRATION (barometer) got no COMMAND_ACK "
                           f"within {node.ack_max:g} s: no command in progress to judge")
    if acks[0].msg.result != IN_PROGRESS:
        raise Inconclusive("MAV_CMD_PREFLIGHT_CALIBRATION (barometer) was answered "
                           f"{result_name(acks[0].msg.result)} at once: no command in progress to judge")
    return since


@rules("MAV-CMD-1", "MAV-CMD-3")
def test_command_long_gets_one_ack(node):
    """MAV-CMD-1: COMMAND_LONG answered by a COMMAND_ACK with its command and a MAV_RESULT;
    MAV-CMD-3: one final ACK for it."""
    since = node.command_long(PROBE, 1)
    node.expect_ack(since, PROBE, "MAV-CMD-1")


@rules("MAV-CMD-2", "MAV-CMD-3")
def test_command_int_gets_one_ack(node):
    """MAV-CMD-2: COMMAND_INT answered the same way (MAV_RESULT_COMMAND_LONG_ONLY is an answer)."""
    since = node.command_int(PROBE, 1)
    node.expect_ack(since, PROBE, "MAV-CMD-2")


@rules("MAV-CMD-3")
def test_retransmission_is_answered_again(node):
    """MAV-CMD-3 (D-4): the same command resent with confirmation 1 gets its own final ACK,
    one per transmission."""
    first = node.command_long(PROBE, 1)
    node.expect_ack(first, PROBE, "MAV-CMD-3", what="the command's first transmission")
    again = node.command_long(PROBE, 1, confirmation=1)
    node.expect_ack(again, PROBE, "MAV-CMD-3", what="the command resent with confirmation 1")


@rules("MAV-CMD-4")
def test_ack_names_the_requester(node):
    """MAV-CMD-4 (SHOULD): COMMAND_ACK.target_system and target_component are the runner's."""
    since = node.command_long(PROBE, 1)
    ack = node.expect_ack(since, PROBE, "MAV-CMD-1", once_rule=None)
    got = (ack.msg.target_system, ack.msg.target_component)
    node.expect_true(got == node.gcs, "MAV-CMD-4", f"COMMAND_ACK.target_system/component {node.gcs[0]}/{node.gcs[1]}",
                     f"{got[0]}/{got[1]}")


@rules("MAV-CMD-5")
def test_unknown_command_is_unsupported(node):
    """MAV-CMD-5: a command id no MAV_CMD has is answered MAV_RESULT_UNSUPPORTED."""
    since = node.command_long(UNKNOWN_COMMAND)
    node.expect_ack(since, UNKNOWN_COMMAND, "MAV-CMD-5", results=(node.mav.MAV_RESULT_UNSUPPORTED,),
                    once_rule=None, what=f"COMMAND_LONG with command {UNKNOWN_COMMAND} (no MAV_CMD)")


@rules("MAV-CMD-14")
def test_command_for_another_system_is_left_alone(node):
    """MAV-CMD-14: a command whose target_system is another system's is not acknowledged."""
    other = node.sysid % 254 + 1  # 1..255, never the vehicle's, never 0 (the broadcast)
    since = node.command_long(PROBE, 1, target_system=other)
    node.expect_no_ack(since, PROBE, "MAV-CMD-14", f"a COMMAND_LONG for system {other}")


@rules("MAV-CMD-14")
def test_command_for_another_component_is_left_alone(node):
    """MAV-CMD-14: a command for the vehicle's system but another component (a camera's,
    MAV_COMP_ID_CAMERA) is not acknowledged by the autopilot."""
    other = node.mav.MAV_COMP_ID_CAMERA if node.compid != node.mav.MAV_COMP_ID_CAMERA else node.mav.MAV_COMP_ID_GIMBAL
    since = node.command_long(PROBE, 1, target_component=other)
    node.expect_no_ack(since, PROBE, "MAV-CMD-14", f"a COMMAND_LONG for component {other}")


@rules("MAV-CMD-15")
def test_command_to_component_zero_is_answered(node):
    """MAV-CMD-15 (SHOULD): target_component 0 (every component of the system) is answered."""
    since = node.command_long(PROBE, 1, target_component=0)
    ack = node.expect_ack(since, PROBE, "MAV-CMD-15", once_rule=None, what="a COMMAND_LONG for component 0")
    node.info(f"MAV-CMD-15: answered {result_name(ack.msg.result)}")


@rules("MAV-CMD-11", "MAV-CMD-12")
def test_command_in_progress_ends(node):
    """MAV-CMD-12: every COMMAND_ACK MAV_RESULT_IN_PROGRESS of the long-running command
    carries progress 0..100 or 255; MAV-CMD-11: a final COMMAND_ACK ends it within
    in_progress_final_max_s. Skipped when the vehicle answers the command at once."""
    since = start_long_command(node)
    limit = float(node.params["in_progress_final_max_s"])
    node.link.wait_for(lambda: any(a.msg.result != IN_PROGRESS for a in node.acks(since, CALIBRATION)), limit)
    acks = node.acks(since, CALIBRATION)
    node.expect_frames([a for a in acks if a.msg.result == IN_PROGRESS],
                       lambda a: None if a.msg.progress <= 100 or a.msg.progress == 255 else f"progress {a.msg.progress}",
                       "MAV-CMD-12", "COMMAND_ACK.progress 0..100, or 255 (unknown), with MAV_RESULT_IN_PROGRESS")
    final = [a for a in acks if a.msg.result != IN_PROGRESS]
    node.expect_true(bool(final), "MAV-CMD-11", f"a final COMMAND_ACK within {limit:g} s of MAV_RESULT_IN_PROGRESS",
                     f"{len(acks)} COMMAND_ACK(s), all MAV_RESULT_IN_PROGRESS")


@rules("MAV-CMD-13")
def test_command_again_while_in_progress_is_busy(node):
    """MAV-CMD-13 (SHOULD): the long-running command sent again while in progress is
    answered MAV_RESULT_TEMPORARILY_REJECTED (ArduPilot's get_task refuses a second task
    for the same command and requester). Skipped when the vehicle answers it at once."""
    since = start_long_command(node)
    again = node.command_long(CALIBRATION, 0, 0, 1)
    node.link.wait_for(lambda: bool(node.acks(again, CALIBRATION)), node.ack_max)
    first = node.acks(again, CALIBRATION)
    node.link.wait_for(lambda: any(a.msg.result != IN_PROGRESS for a in node.acks(since, CALIBRATION)),
                       float(node.params["in_progress_final_max_s"]))
    node.expect_true(bool(first) and first[0].msg.result == MAV.MAV_RESULT_TEMPORARILY_REJECTED, "MAV-CMD-13",
                     "the same command while in progress answered MAV_RESULT_TEMPORARILY_REJECTED",
                     result_name(first[0].msg.result) if first else "no COMMAND_ACK")
