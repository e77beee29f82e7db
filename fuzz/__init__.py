"""fuzz: the fuzz campaigns behind ``mcp-fuzz`` — engines (``fuzz.engine_stateless``,
``fuzz.engine_stateful``), their inputs (``fuzz.mutators``), oracles (``fuzz.oracles``: the
judge plus liveness, the process's fate and the vehicle's record), triage and findings
(``fuzz.triage``, ``fuzz.findings``), replay (``fuzz.replay``, ``fuzz.replay_cli``). Drives
the node through ``harness``; never imports ``conformance`` or ``reference_impl``."""
