"""harness: the node under test, as the runner and the fuzzer both drive it.

The target driver (``harness.driver``: the one UDP socket, sends, waits), the session over a
whole run in each role (``harness.session``: attach, spawn or the embedded reference node,
the simulated vehicle, restarts; ``harness.manager_session`` with the runner's drones in
``harness.manager_mission``), liveness (``harness.liveness``), the processes started
(``harness.procs``), the run's parameters (``harness.config``), outcomes other than passing
(``harness.errors``) and signals (``harness.interrupts``). Below ``conformance`` and
``fuzz``, which never import each other; above the judge."""
