"""Small MCP conversations written as pcap files with scapy, for the mcp-capture tests."""

from __future__ import annotations

from pathlib import Path

from scapy.layers.inet import IP, UDP
from scapy.layers.l2 import Ether
from scapy.packet import Raw
from scapy.utils import wrpcap

from mcp_conform.spec.codec import Action, Message, MissionItem, encode

MANAGER = ("127.0.0.1", 7889)
BCAST = ("127.255.255.255", 7890)
ITEM = MissionItem(0.0, 0.0, 0.0, 0.0, 35.771103, -78.674659, 3.0, 1, 16, 1, 1, 3, 0, 1)


def drone_addr(drone: int) -> tuple[str, int]:
    return ("127.0.0.1", 40000 + drone)


class Script:
    """Datagrams with times, written to a pcap (Ethernet, as ``tcpdump -i lo`` writes)."""

    def __init__(self) -> None:
        self.t = 1_700_000_000.0
        self.packets: list[Ether] = []

    def send(self, src: tuple[str, int], dst: tuple[str, int], data: bytes, after: float = 0.01) -> int:
        self.t += after
        p = Ether() / IP(src=src[0], dst=dst[0]) / UDP(sport=src[1], dport=dst[1]) / Raw(data)
        p.time = self.t
        self.packets.append(p)
        return len(self.packets) - 1

    def msg(self, src_id: int, dst_id: int, seq: int, action: Action, payload=None, after: float = 0.01,
            src: tuple[str, int] | None = None, dst: tuple[str, int] | None = None) -> int:
        src = src or (MANAGER if src_id == 0 else drone_addr(src_id))
        dst = dst or (MANAGER if dst_id == 0 else BCAST if dst_id == 0xFFFF else drone_addr(dst_id))
        return self.send(src, dst, encode(Message(dst_id, src_id, seq, action, payload)), after)

    def write(self, path: Path) -> Path:
        wrpcap(str(path), self.packets, linktype=1)
        return path


def mission(drones=(1, 2), lose_ack_of: int | None = None) -> Script:
    """Challenge 1 for ``drones``: Mission_Ready, ACK, Start_Mission, ACK, WP_List, ACK,
    End_Mission, ACK. ``lose_ack_of``: that drone's first WP_List ACK is not in the capture,
    so the manager retransmits (a capture point that missed a datagram)."""
    s = Script()
    seq = {d: 100 * d for d in drones}
    mseq = 5000

    def drone_acks(d: int, acked: int) -> None:
        seq[d] += 1
        s.msg(d, 0, seq[d], Action.ACK, acked, after=0.001)

    for d in drones:
        s.msg(d, 0, seq[d], Action.MISSION_READY)
        mseq += 1
        s.msg(0, d, mseq, Action.ACK, seq[d], after=0.001)
    for action, payload in ((Action.START_MISSION, None), (Action.WP_LIST, (ITEM, ITEM._replace(seq=2))),
                            (Action.END_MISSION, None)):
        for d in drones:
            mseq += 1
            s.msg(0, d, mseq, action, payload)
            if action == Action.WP_LIST and d == lose_ack_of:
                seq[d] += 1  # the ACK the capture missed took a number (D-5)
                s.msg(0, d, mseq, action, payload, after=5.0)  # the manager's retransmission
            drone_acks(d, mseq)
    return s
