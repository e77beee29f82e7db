"""The conformance cases, one module per rule group (HDR, ACK, SEQ, DUP, RTX, BLK, PAY,
ROB, FLOW, TRN). Each case names the rule IDs it verifies, sends, then calls one verify
helper of the ``node`` fixture (``conformance.drone_case.CaseContext``)."""
