"""spec.scapy_mcp: a layer built from the spec's header table, pcap dissection, answers()."""

from __future__ import annotations

from pathlib import Path

import pytest
from scapy.layers.inet import IP, UDP
from scapy.packet import Raw
from scapy.utils import rdpcap, wrpcap

from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import Action, Message, MissionItem, encode
from mcp_conform.spec.mavframe import heartbeat_frame
from mcp_conform.spec.scapy_mcp import MCP, PORTS, MCPAck, MCPItemList, MCPMissionItem, MCPReadyId

MANAGER_PORT = SPEC.protocol["ports"]["manager"]
DRONE_PORT = SPEC.protocol["ports"]["drone"]
ITEM = MissionItem(5.0, 0.0, 0.0, 0.0, 35.5, -78.5, 3.0, 2, 19, 1, 0, 3, 0, 1)


def _udp(data: bytes, sport: int, dport: int) -> IP:
    return IP(src="127.0.0.1", dst="127.0.0.1") / UDP(sport=sport, dport=dport) / Raw(data)


def test_fields_follow_the_spec_header_table() -> None:
    names = [f.name for f in MCP.fields_desc]
    assert names == [f["name"] for f in SPEC.header["fields"]]
    assert len(bytes(MCP())) == SPEC.header["size"]
    assert bytes(MCP())[:9] == SPEC.preamble
    assert PORTS == (7889, 7890)


def test_built_header_equals_the_codec() -> None:
    for action in (Action.START_MISSION, Action.END_MISSION, Action.WP_OFF):
        msg = Message(3, 0, 0xBEEF, action, None)
        assert bytes(MCP(dst=3, src=0, seq=0xBEEF, action=int(action))) == encode(msg)
    ack = MCP(dst=0, src=3, seq=1, action=int(Action.ACK)) / MCPAck(ack_seq=0xBEEF)
    assert bytes(ack) == encode(Message(0, 3, 1, Action.ACK, 0xBEEF))
    wp = MCP(dst=1, src=0, seq=4, action=int(Action.WP_LIST)) / MCPItemList(
        items=[MCPMissionItem(**ITEM._asdict()), MCPMissionItem(**ITEM._asdict())])
    assert bytes(wp) == encode(Message(1, 0, 4, Action.WP_LIST, (ITEM, ITEM)))


def test_pcap_round_trip_dissects_mcp(tmp_path: Path) -> None:
    frames = [
        _udp(encode(Message(0, 1, 10, Action.MISSION_READY, 1)), DRONE_PORT, MANAGER_PORT),
        _udp(encode(Message(1, 0, 20, Action.ACK, 10)), MANAGER_PORT, DRONE_PORT),
        _udp(encode(Message(1, 0, 21, Action.WP_LIST, (ITEM, ITEM))), MANAGER_PORT, DRONE_PORT),
        _udp(encode(Message(1, 0, 22, Action.WP_ON, ITEM)), MANAGER_PORT, DRONE_PORT),
        _udp(encode(Message(1, 0, 23, Action.MAV_PASSTHROUGH, heartbeat_frame())), MANAGER_PORT, DRONE_PORT),
        _udp(b"short", MANAGER_PORT, DRONE_PORT),
    ]
    path = tmp_path / "mcp.pcap"
    wrpcap(str(path), frames)
    got = rdpcap(str(path))
    assert len(got) == len(frames)
    ready, ack, wp_list, wp_on, passthrough, short = got
    assert ready[MCP].action == Action.MISSION_READY and ready[MCPReadyId].drone_id == 1
    assert ack[MCP].src == 0 and ack[MCPAck].ack_seq == 10
    assert wp_list[MCPItemList].count == 2
    item = wp_list[MCPItemList].items[1]
    # `command` is also a Packet method, so the field is read with getfieldval
    assert (item.x, item.y, item.getfieldval("command"), item.frame) == (35.5, -78.5, 19, 3)
    assert wp_on[MCPMissionItem].seq == 2
    assert bytes(passthrough[MCP].payload) == heartbeat_frame()
    assert MCP not in short and bytes(short[Raw]) == b"short"
    assert "Mission_Ready" in ready.summary()


def test_answers_pairs_an_ack_with_its_message() -> None:
    cmd = MCP(encode(Message(5, 0, 300, Action.START_MISSION, None)))
    ack = MCP(encode(Message(0, 5, 77, Action.ACK, 300)))
    assert ack.answers(cmd)
    assert ack.hashret() == cmd.hashret()
    # whole packets: scapy pairs them through IP/UDP too
    req = IP(bytes(_udp(bytes(cmd), MANAGER_PORT, DRONE_PORT)))
    rep = IP(bytes(_udp(bytes(ack), DRONE_PORT, MANAGER_PORT)))
    assert rep.answers(req) and rep.hashret() == req.hashret()


@pytest.mark.parametrize("ack", [
    Message(0, 5, 77, Action.ACK, 301),   # wrong acknowledged seq (MCP-RTX-2)
    Message(0, 6, 77, Action.ACK, 300),   # from another node (MCP-ACK-3)
    Message(9, 5, 77, Action.ACK, 300),   # to another node (MCP-ACK-3)
], ids=["wrong_seq", "wrong_src", "wrong_dst"])
def test_answers_rejects_a_mismatched_ack(ack: Message) -> None:
    cmd = MCP(encode(Message(5, 0, 300, Action.START_MISSION, None)))
    assert not MCP(encode(ack)).answers(cmd)


def test_answers_never_pairs_non_acks_or_ack_of_ack() -> None:
    cmd = MCP(encode(Message(5, 0, 300, Action.START_MISSION, None)))
    other = MCP(encode(Message(0, 5, 300, Action.MISSION_READY, None)))
    assert not other.answers(cmd)
    ack1 = MCP(encode(Message(5, 0, 300, Action.ACK, 1)))
    ack2 = MCP(encode(Message(0, 5, 2, Action.ACK, 300)))
    assert not ack2.answers(ack1)  # MCP-ACK-6: an ACK is never ACKed
    assert not cmd.answers(ack2)
    assert not ack2.answers(Raw(b"x"))
