"""What a stateless case waits for (issue 21 item 6: judged cases/s): a backend's close after a
framing error is allowed, so no grace is spent telling it from a death (that shows at the next
case); a close on a clean connection still gets it; a judged effect that moved the flight
state counts as a passed probe."""

from __future__ import annotations

import struct
import time

import pytest

from fuzz.stream_campaign import Backend
from fuzz.stream_mutators import Case, Write
from spec import NSQD
from spec.stream_codec import encode

pytestmark = pytest.mark.nsqd


@pytest.fixture
def backend():
    b = Backend(None, None)  # the embedded reference backend, spawned
    yield b
    b.close()


def test_no_death_grace_after_a_close_the_spec_allows(backend, monkeypatch):
    graces: list[float] = []
    real = backend.death_hit

    def spy(grace: float):
        graces.append(grace)
        return real(grace)

    monkeypatch.setattr(backend, "death_hit", spy)
    lie = Case("length-lie", (Write(struct.pack(">i", 2) + b"\x08"),), note="length 2")
    assert backend.run(lie) is None
    time.sleep(0.3)  # the backend has closed the connection (NSQD-FRM-4); the next case sees it
    assert backend.run(Case("bad-id", (Write(struct.pack(">iB", 5, 200)),), note="id 200")) is None
    assert backend.conn is not None and backend.conn.closed_at is not None
    assert graces and max(graces) == 0.0, graces


def test_a_judged_effect_that_moved_the_state_is_a_passed_probe(backend):
    takeoff, land = encode(NSQD, "TAKEOFF"), encode(NSQD, "LAND")
    for data, name in ((takeoff, "TAKEOFF"), (land, "LAND"), (takeoff, "TAKEOFF")):
        msg = NSQD.message(name)
        case = Case("valid", (Write(data),), True, name, expect=msg.effect.to, or_error=msg.effect.or_error,
                    check=True, msg=name)
        assert backend.run(case) is None
    assert backend.synced  # GROUNDED -> HOVER: the stream was in sync
    msg = NSQD.message("TAKEOFF")
    again = Case("valid", (Write(takeoff),), True, "TAKEOFF", expect=msg.effect.to, check=True, msg="TAKEOFF")
    assert backend.run(again) is None and not backend.synced  # already HOVER: proves nothing
