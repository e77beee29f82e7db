"""The Nsqd backend cases (``mcp-conform --protocol nsqd``), one module per rule group of
``spec/nsqd.yaml`` (FRM, MSG, ROB, CON). Each case names its rule IDs, sends, then calls one
verify helper of the ``node`` fixture (``conformance.nsqd_case.StreamCaseContext``)."""
