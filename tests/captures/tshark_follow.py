"""tshark's "Follow TCP stream" (``-z follow,tcp,raw,N``): the bytes of each direction of
TCP stream ``N`` of a capture, as Wireshark reassembles them."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path


def follow(pcap: Path, stream: int) -> tuple[bytes, bytes]:
    """(node 0's bytes, node 1's bytes) of stream ``stream``: node 0 is the side that spoke
    first (the client, for a conversation with its handshake)."""
    tshark = shutil.which("tshark")
    assert tshark is not None
    out = subprocess.run([tshark, "-r", str(pcap), "-q", "-z", f"follow,tcp,raw,{stream}"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    node0, node1 = bytearray(), bytearray()
    body = out.stdout.split("Node 1:", 1)[1].split("\n", 1)[1]
    for line in body.splitlines():
        if line.startswith("="):
            break
        if line.strip():
            (node1 if line.startswith("\t") else node0).extend(bytes.fromhex(line.strip()))
    return bytes(node0), bytes(node1)
