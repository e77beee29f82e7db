"""MAV_CMD_SET_MESSAGE_INTERVAL on the HEARTBEAT, as ArduCopter answers it (``vehicle.telemetry``'s
docstring: ``GCS_MAVLINK::set_message_interval`` maps HEARTBEAT to its deferred MSG_HEARTBEAT,
-1 sets its interval to 0 and ``deferred_message_to_send_index`` skips it): -1 is ACCEPTED and
the HEARTBEAT stops; 0 restores its default; a positive interval sets it; no stream request
touches it. Sans-I/O: the model with a fake clock."""

from __future__ import annotations

from collections import Counter

from pymavlink.dialects.v20 import ardupilotmega as mav

from tests.vehicle.test_model import ACCEPTED, ack_of, by_type, make

SET, GET = mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAV_CMD_GET_MESSAGE_INTERVAL
HB = mav.MAVLINK_MSG_ID_HEARTBEAT


def beats(model, start: float, end: float, step: float = 0.05) -> int:
    n: Counter = Counter()
    t = start
    while t <= end:
        n.update(m.get_type() for m in model.tick(t))
        t = round(t + step, 6)
    return n["HEARTBEAT"]


def test_minus_one_is_accepted_and_stops_the_heartbeat_until_zero_restores_it() -> None:
    model, gcs = make()
    assert beats(model, 0.0, 3.0) == 4  # 1 Hz, the first at once
    assert ack_of(gcs.command(SET, HB, -1, now=3.0), SET) == ACCEPTED
    assert beats(model, 3.05, 8.0) == 0
    assert by_type(gcs.command(GET, HB, now=8.0), "MESSAGE_INTERVAL").interval_us == -1
    assert ack_of(gcs.command(SET, HB, 0, now=8.0), SET) == ACCEPTED  # the default, 1 s
    assert beats(model, 8.05, 11.0) == 3
    assert by_type(gcs.command(GET, HB, now=11.0), "MESSAGE_INTERVAL").interval_us == 1_000_000


def test_a_positive_interval_sets_the_heartbeat_rate() -> None:
    model, gcs = make()
    model.tick(0.0)
    assert ack_of(gcs.command(SET, HB, 250_000, now=0.0), SET) == ACCEPTED
    assert beats(model, 0.05, 2.0) == 8  # 4 Hz


def test_no_stream_request_stops_the_heartbeat() -> None:
    model, gcs = make()
    model.tick(0.0)
    gcs.send(mav.MAVLink_request_data_stream_message(1, 1, mav.MAV_DATA_STREAM_ALL, 0, 0), 0.0)
    assert beats(model, 0.05, 3.0) == 3


def test_an_interval_under_80_percent_of_the_loop_period_is_capped_at_3_ms() -> None:
    """Issue 39's note: SET_MESSAGE_INTERVAL of 1 us made the vehicle beat at 1 kHz (it capped at
    1 ms). ArduPilot's ``cap_message_interval``: an interval whose ms x 800 is under the loop
    period (2,500 us at ArduCopter's 400 Hz) is ``loop_period_us/800`` = 3 ms, as
    GET_MESSAGE_INTERVAL then reports."""
    for asked in (1, 1000, 3000):
        model, gcs = make()
        model.tick(0.0)
        assert ack_of(gcs.command(SET, HB, asked, now=0.0), SET) == ACCEPTED
        assert by_type(gcs.command(GET, HB, now=0.0), "MESSAGE_INTERVAL").interval_us == 3000, asked
        assert beats(model, 0.001, 0.301, step=0.001) == 100, asked  # every 3 ms, 0.3 s
    model, gcs = make()
    model.tick(0.0)
    assert ack_of(gcs.command(SET, HB, 4000, now=0.0), SET) == ACCEPTED  # 4 ms x 800 > 2,500 us: kept
    assert by_type(gcs.command(GET, HB, now=0.0), "MESSAGE_INTERVAL").interval_us == 4000
