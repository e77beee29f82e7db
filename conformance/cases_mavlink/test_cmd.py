"""CMD — the command protocol (https://mavlink.io/en/services/command.html): COMMAND_LONG and
COMMAND_INT answered by one COMMAND_ACK naming the command, unknown commands UNSUPPORTED, a
retransmission (confirmation > 0) answered again, commands for other systems and components
left alone. The command the runner sends is MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: it
changes nothing on a vehicle, and any MAV_RESULT is an answer."""

from __future__ import annotations

from mcp_conform.conformance.marks import rules
from mcp_conform.conformance.mavlink_case import UNKNOWN_COMMAND, result_name
from mcp_conform.spec import MAVLINK

PROBE = MAVLINK.dialect.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES


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
