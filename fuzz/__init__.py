"""fuzz: the fuzz campaigns behind ``mcp-fuzz`` — engines (``fuzz.engine_stateless``,
``fuzz.engine_stateful``), their inputs (``fuzz.mutators``), oracles (``fuzz.oracles``: the
judge plus liveness, the process's fate and the vehicle's record), triage and findings
(``fuzz.triage``, ``fuzz.findings``), replay (``fuzz.replay``, ``fuzz.replay_cli``); one
campaign loop for every protocol (``fuzz.loop``), each protocol's parts a plug-in of it
(MCP: ``fuzz.campaign``; Nsqd: ``fuzz.nsqd_campaign``, ``fuzz.nsqd_engine``,
``fuzz.nsqd_triage``). Drives
the node through ``harness``; never imports ``conformance`` or ``reference_impl``."""
