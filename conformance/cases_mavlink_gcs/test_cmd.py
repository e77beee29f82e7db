"""CMD — the ground station's side of the command protocol
(https://mavlink.io/en/services/command.html): its commands addressed to the vehicle, the first
transmission with confirmation 0, resent with confirmation incremented while no COMMAND_ACK
comes, given up at a bound, not resent after MAV_RESULT_IN_PROGRESS, not taken as answered by
the ACK of another command; positions of COMMAND_INT in degE7. The runner's vehicle departs
from ArduPilot for the first command the ground station sends (``Behaviour``)."""

from __future__ import annotations

from mcp_conform.conformance.cases_mavlink_gcs.mavlink_gcs_services import (
    GLOBAL_FRAMES,
    degrees_sent,
)
from mcp_conform.conformance.marks import rules
from mcp_conform.harness.errors import Inconclusive
from mcp_conform.spec import MAVLINK
from mcp_conform.vehicle.behaviour import Behaviour

WITHHOLD = Behaviour("withhold-command-ack", withhold_command_ack=True)
WRONG_ACK = Behaviour("wrong-command-ack", wrong_command_ack=True)
IN_PROGRESS = Behaviour("command-in-progress", in_progress_s=float(MAVLINK.params["command_resend_window_s"]))
#: the messages whose target_system/target_component address the vehicle (MAV-CMD-16)
ADDRESSED = ("COMMAND_LONG", "COMMAND_INT", "PARAM_SET", "PARAM_REQUEST_READ", "PARAM_REQUEST_LIST",
             "MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_REQUEST_LIST", "MISSION_REQUEST_INT",
             "MISSION_REQUEST", "MISSION_ACK", "MISSION_CLEAR_ALL", "MISSION_SET_CURRENT")


def _window(node) -> float:
    return float(node.params["command_resend_window_s"])


@rules("MAV-CMD-7")
def test_first_transmission_has_confirmation_0(node):
    """MAV-CMD-7: the first COMMAND_LONG of each command has confirmation 0."""
    node.run()
    node.settle()
    firsts = {}
    for r in node.from_gcs("COMMAND_LONG"):
        firsts.setdefault(r.msg.command, r)
    node.expect_frames(node.need(list(firsts.values()), "COMMAND_LONG"),
                       lambda r: None if r.msg.confirmation == 0 else f"confirmation {r.msg.confirmation}",
                       "MAV-CMD-7", "confirmation 0 on a command's first COMMAND_LONG")


@rules("MAV-CMD-16")
def test_requests_are_addressed_to_the_vehicle(node):
    """MAV-CMD-16: commands, parameter and mission messages carry the vehicle's system ID as
    target_system and its component ID (or 0) as target_component."""
    node.run()
    node.settle()
    sysid, compid = node.vehicle_ids
    node.expect_frames(node.need(node.from_gcs(*ADDRESSED), "command, parameter or mission message"),
                       lambda r: None if r.msg.target_system == sysid and r.msg.target_component in (compid, 0)
                       else f"{r.name} to {r.msg.target_system}/{r.msg.target_component}", "MAV-CMD-16",
                       f"target_system {sysid}, target_component {compid} or 0")


@rules("MAV-CMD-18")
def test_command_int_positions_in_degE7(node):
    """MAV-CMD-18 (D-6): a COMMAND_INT in a global frame carries x, y as degrees * 1E7."""
    node.run()
    node.settle()
    frames = [r for r in node.from_gcs("COMMAND_INT") if r.msg.frame in GLOBAL_FRAMES]
    node.expect_frames(node.need(frames, "COMMAND_INT in a global frame"),
                       lambda r: f"x {r.msg.x}, y {r.msg.y}: degrees" if degrees_sent(r.msg.x, r.msg.y) else None,
                       "MAV-CMD-18", "x, y in degrees * 1E7")


@rules("MAV-CMD-6")
def test_command_resent_without_ack(node):
    """MAV-CMD-6 (D-3): with no COMMAND_ACK, the command is sent again within
    command_resend_window_s."""
    node.run(WITHHOLD)
    command = node.first_command()
    node.wait(lambda: len(node.transmissions(command)) > 1, _window(node))
    sent = node.transmissions(command)
    node.expect_true(len(sent) > 1, "MAV-CMD-6", f"{node.command_name(command)} sent again within {_window(node):g} s "
                     "when no COMMAND_ACK comes", "sent once")


def _resent(node, command):
    """The transmissions of ``command`` under WITHHOLD, until the ground station gives up."""
    bound = int(node.params["command_retries_max"])
    return node.resends(lambda: node.transmissions(command), bound, _window(node), (bound + 2) * _window(node))


@rules("MAV-CMD-8")
def test_resends_increment_confirmation(node):
    """MAV-CMD-8 (SHOULD): the n-th retransmission of a COMMAND_LONG has confirmation n."""
    node.run(WITHHOLD)
    command = node.first_command()
    sent = [r for r in _resent(node, command) if r.name == "COMMAND_LONG"]
    node.need(sent[1:], "retransmission of a COMMAND_LONG")
    node.expect_frames(sent, lambda r: None if r.msg.confirmation == min(sent.index(r), 255)
                       else f"transmission {sent.index(r)} with confirmation {r.msg.confirmation}",
                       "MAV-CMD-8", "confirmation 0, 1, 2, ... on the transmissions")


@rules("MAV-CMD-9")
def test_command_given_up(node):
    """MAV-CMD-9 (D-3): at most command_retries_max resends of a command never acknowledged."""
    node.run(WITHHOLD)
    command = node.first_command()
    sent = _resent(node, command)
    node.need(sent[1:], "retransmission of a command")
    bound = int(node.params["command_retries_max"])
    node.expect_true(len(sent) - 1 <= bound, "MAV-CMD-9", f"at most {bound} resends of {node.command_name(command)}",
                     f"{len(sent) - 1} resends")


@rules("MAV-CMD-10")
def test_no_resend_while_in_progress(node):
    """MAV-CMD-10 (SHOULD): after COMMAND_ACK MAV_RESULT_IN_PROGRESS, no resend until the final
    result (the runner holds it command_resend_window_s)."""
    node.run(IN_PROGRESS)
    command = node.first_command()
    progress = MAVLINK.dialect.MAV_RESULT_IN_PROGRESS

    def acks():
        return [(t, m) for t, m in node.runner_sent("COMMAND_ACK") if m.command == command]
    node.wait(lambda: any(m.result != progress for _, m in acks()), _window(node) + 2.0)
    said = [t for t, m in acks() if m.result == progress]
    final = [t for t, m in acks() if m.result != progress]
    if not said or not final:
        raise Inconclusive("the runner's IN_PROGRESS and final COMMAND_ACK did not both go out")
    again = [r for r in node.transmissions(command) if said[0] < r.t < final[0]]
    # one resend soon after IN_PROGRESS went out may have crossed it (sent before the ground
    # station had it: its timer first, a segment the link lost): it proves the rule broken
    # once another follows, or once it came later than an answer's way may take
    # (command_ack_max_s); a ground station that ignores IN_PROGRESS resends all through the
    # runner's hold (command_resend_window_s), a few times
    crossed = len(again) == 1 and again[0].t - said[0] <= float(node.params["command_ack_max_s"])
    node.expect_true(not again or crossed, "MAV-CMD-10",
                     "no resend between MAV_RESULT_IN_PROGRESS and the final COMMAND_ACK",
                     f"{len(again)} resend(s), the first {again[0].t - said[0]:.2f} s after IN_PROGRESS" if again else "")


@rules("MAV-CMD-17")
def test_ack_of_another_command_is_no_answer(node):
    """MAV-CMD-17: after a COMMAND_ACK naming another command, the command is still resent."""
    node.run(WRONG_ACK)
    command = node.first_command()
    node.wait(lambda: len(node.transmissions(command)) > 1, _window(node))
    if len(node.transmissions(command)) < 2:  # no resend: of this ACK's doing, or none ever (MAV-CMD-6's)?
        node.run(WITHHOLD)
        first = node.first_command()
        if not node.wait(lambda: len(node.transmissions(first)) > 1, _window(node)):
            raise Inconclusive("the ground station resends no command, ACK or none (MAV-CMD-6 judges that)")
        node.run(WRONG_ACK)
        command = node.first_command()
        node.wait(lambda: len(node.transmissions(command)) > 1, _window(node))
    node.expect_true(len(node.transmissions(command)) > 1, "MAV-CMD-17",
                     f"{node.command_name(command)} resent after a COMMAND_ACK for another command",
                     "not resent: the ACK of another command was taken as its answer")
