"""The MAVLink ground-station cases (``mcp-conform --protocol mavlink --role gcs``), one module
per rule group of ``spec/mavlink.yaml`` (HB, CMD, PRM, MIS) with the rules of roles ``gcs``
and ``any``. The runner is the vehicle; each case asks for the run it observes (the ground
station against a vehicle that answers as ArduPilot, or departs from it on purpose), then
calls one verify helper of the ``node`` fixture
(``conformance.mavlink_gcs_case.MavlinkGcsCaseContext``)."""
