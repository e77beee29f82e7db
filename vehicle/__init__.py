"""Simulated MAVLink autopilot (ArduCopter as a companion computer sees it).

Used by the reference drone as its default autopilot and by the conformance runner as its
observation point on a drone's MAVLink link. All timestamps are ``time.monotonic()``.

>>> from vehicle import SimVehicle, make_probe
>>> with SimVehicle(gps_fix_delay=0.0) as v:      # doctest: +SKIP
...     url = v.url                               # "tcp:127.0.0.1:PORT" for pymavlink
...     v.wait_for(lambda: v.armed, timeout=5)
"""

from .codec import Decoder, Encoder
from .links import TRANSPORTS, start_for_node
from .model import VehicleConfig, VehicleModel
from .probe import PROBE_PREFIX, make_probe, probe_token
from .records import (
    COPTER_MODE_NAMES,
    COPTER_MODES,
    EVENT_KINDS,
    REQUESTS,
    Event,
    Frame,
    Unparsed,
    describe_request,
    is_rtl_request,
    mode_name,
)
from .server import SimVehicle

__all__ = [
    "COPTER_MODES",
    "COPTER_MODE_NAMES",
    "EVENT_KINDS",
    "PROBE_PREFIX",
    "REQUESTS",
    "Decoder",
    "Encoder",
    "Event",
    "Frame",
    "SimVehicle",
    "TRANSPORTS",
    "Unparsed",
    "VehicleConfig",
    "VehicleModel",
    "describe_request",
    "is_rtl_request",
    "make_probe",
    "mode_name",
    "probe_token",
    "start_for_node",
]
