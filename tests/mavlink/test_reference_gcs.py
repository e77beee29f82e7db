"""The reference ground station's mission upload (``reference_impl.mavlink_gcs.ReferenceGcs.upload``)
against a scripted vehicle on loopback: which MISSION_ACK ends it.

mavlink.io's mission page (https://mavlink.io/en/services/mission.html): an error MISSION_ACK
"must cancel the operation" (MAV-MIS-24), but "Out-of-sequence messages in mission
upload/download are recoverable, and are not treated as errors", and in its ArduPilot section
"A MISSION_ACK returning an error value (NACK) does not terminate the upload": ArduPilot answers
an item out of sequence (a late copy) with MAV_MISSION_INVALID_SEQUENCE, then re-requests the
item it expects (the spec's erratum E-1). The reference ended the upload on any MISSION_ACK and
left the vehicle mid-upload, re-requesting an item no one sent (the gcs role's simulator found
it on a lossy link: tests/sim/test_mavlink_gcs_sim.py).
"""

from __future__ import annotations

import threading
import time
from typing import Any

import pytest
from pymavlink import mavutil

from mcp_conform.reference_impl.mavlink_gcs import ReferenceGcs, mav
from mcp_conform.vehicle.ports import free_port

VEHICLE = (1, 1)


class Upload:
    """The reference's upload of its default plan (four items) in a thread, to a pymavlink
    vehicle the test scripts (``udpin`` on a free loopback port)."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        monkeypatch.setenv("MAVLINK20", "1")  # ReferenceGcs sets it: restored after the test
        port = free_port()
        self.vehicle = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=VEHICLE[0],
                                                  source_component=VEHICLE[1])
        self.gcs = ReferenceGcs(f"udpout:127.0.0.1:{port}", log=lambda text: None)
        self.gcs.target = VEHICLE
        self.gcs.mission_retries = 1  # a failing run ends sooner: one resend
        self.items = self.gcs.plan(None)
        self.result: list[bool] = []
        self.thread = threading.Thread(target=lambda: self.result.append(self.gcs.upload(self.items)), daemon=True)

    def __enter__(self) -> Upload:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.thread.join(timeout=10.0)
        self.gcs.close()
        self.vehicle.close()

    def recv(self, name: str, where: Any = None, timeout: float = 2.0) -> Any | None:
        """The ground station's next ``name`` (and ``where(msg)``) within ``timeout`` s."""
        end = time.monotonic() + timeout
        while (left := end - time.monotonic()) > 0:
            msg = self.vehicle.recv_match(type=name, blocking=True, timeout=min(left, 0.2))
            if msg is not None and (where is None or where(msg)):
                return msg
        return None

    def request(self, seq: int) -> Any | None:
        """MISSION_REQUEST_INT for ``seq``; the item of that seq that answered it."""
        self.vehicle.mav.mission_request_int_send(255, mav.MAV_COMP_ID_MISSIONPLANNER, seq,
                                                  mav.MAV_MISSION_TYPE_MISSION)
        return self.recv("MISSION_ITEM_INT", lambda m: m.seq == seq)

    def ack(self, result: int) -> None:
        self.vehicle.mav.mission_ack_send(255, mav.MAV_COMP_ID_MISSIONPLANNER, result, mav.MAV_MISSION_TYPE_MISSION)


def test_an_invalid_sequence_nack_leaves_the_upload_going_on(monkeypatch):
    """ArduPilot's MAV_MISSION_INVALID_SEQUENCE after item 0 (the answer to a late copy of it),
    then its request for item 1: the ground station answers it and every later one, and the
    upload ends on MAV_MISSION_ACCEPTED. Before, it ended on the NACK and item 1 never came."""
    with Upload(monkeypatch) as up:
        count = up.recv("MISSION_COUNT")
        assert count is not None and count.count == len(up.items) == 4
        assert up.request(0) is not None
        up.ack(mav.MAV_MISSION_INVALID_SEQUENCE)
        got = [up.request(seq) for seq in range(1, count.count)]
        assert all(got), [m is not None for m in got]
        up.ack(mav.MAV_MISSION_ACCEPTED)
        up.thread.join(timeout=5.0)
        assert up.result == [True]


@pytest.mark.parametrize("error", ["MAV_MISSION_ERROR", "MAV_MISSION_NO_SPACE", "MAV_MISSION_DENIED"])
def test_an_error_ack_ends_the_upload(monkeypatch, error):
    """Any other error MISSION_ACK cancels the upload (MAV-MIS-24): the request for item 1 that
    follows it is not answered, and the upload reports failure."""
    with Upload(monkeypatch) as up:
        assert up.recv("MISSION_COUNT") is not None
        assert up.request(0) is not None
        up.ack(getattr(mav, error))
        up.thread.join(timeout=5.0)
        assert up.result == [False]
        assert up.request(1) is None
