"""The MAVLink vehicle cases (``mcp-conform --protocol mavlink``), one module per rule group
of ``spec/mavlink.yaml`` (HB, CMD, PRM, MIS). The runner is a ground station; each case names
its rule IDs, sends, then calls one verify helper of the ``node`` fixture
(``conformance.mavlink_case.MavlinkCaseContext``; its microservices: ``mavlink_services``)."""
