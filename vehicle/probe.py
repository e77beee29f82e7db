"""Passthrough probes: MAVLink frames the conformance runner can recognise one by one.

A probe is one MAVLink v2 STATUSTEXT frame (severity INFO) whose text is
``"MCPPROBE:<token>"``. The runner sends it inside an MCP Mav_Passthrough; a drone that
forwards passthrough frames to its autopilot delivers it to the simulated vehicle, which
counts probes by their decoded text, so the count is the same whether the drone forwards
the frame as it came (v2) or re-encodes it as v1.
"""

from __future__ import annotations

from pymavlink.dialects.v10 import ardupilotmega as mavlink1
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

PROBE_PREFIX = "MCPPROBE:"
#: STATUSTEXT.text holds 50 characters; the prefix takes 9.
MAX_TOKEN_LEN = 50 - len(PROBE_PREFIX)


def make_probe(
    token: str,
    srcsys: int = 255,
    srccomp: int = 190,
    seq: int = 0,
    *,
    version: int = 2,
) -> bytes:
    """Build one complete probe frame (MAVLink v2 unless ``version=1``) for ``token``.

    ``token`` must be printable ASCII without spaces, 1..41 characters; ``seq`` is the
    frame's sequence number (0..255). Raises ``ValueError`` on a bad argument.
    """
    if not token or len(token) > MAX_TOKEN_LEN:
        raise ValueError(f"probe token must be 1..{MAX_TOKEN_LEN} characters: {token!r}")
    if not all(33 <= ord(c) <= 126 for c in token):
        raise ValueError(f"probe token must be printable ASCII without spaces: {token!r}")
    for name, value in (("srcsys", srcsys), ("srccomp", srccomp), ("seq", seq)):
        if not 0 <= value <= 255:
            raise ValueError(f"{name} must be 0..255: {value}")
    if version not in (1, 2):
        raise ValueError(f"version must be 1 or 2: {version}")
    dialect = mavlink2 if version == 2 else mavlink1
    mav = dialect.MAVLink(None, srcSystem=srcsys, srcComponent=srccomp)
    mav.seq = seq
    text = (PROBE_PREFIX + token).encode("ascii")
    msg = dialect.MAVLink_statustext_message(dialect.MAV_SEVERITY_INFO, text)
    return bytes(msg.pack(mav))


def probe_token(text: object) -> str | None:
    """The token of a decoded STATUSTEXT ``text`` if it is a probe, else ``None``."""
    if isinstance(text, (bytes, bytearray)):
        text = bytes(text).split(b"\0", 1)[0].decode("ascii", "replace")
    if not isinstance(text, str):
        return None
    text = text.split("\0", 1)[0]
    if not text.startswith(PROBE_PREFIX) or len(text) == len(PROBE_PREFIX):
        return None
    return text[len(PROBE_PREFIX):]
