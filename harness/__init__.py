"""harness: the node under test, as the runner and the fuzzer both drive it.

What the runner needs of any node under test (``harness.node``: ``NodeUnderTest``), the
target driver (``harness.driver``: the one UDP socket, sends, waits), the session over a
whole run in each role (``harness.drone_session``: attach, spawn or the embedded reference node,
the simulated vehicle, restarts; ``harness.manager_session`` with the runner's drones in
``harness.drone_players``; ``harness.nsqd_session`` for a stream protocol's backend; all
on ``harness.session_base``), liveness (``harness.liveness``), the processes started
(``harness.procs``), the run's parameters (``harness.config``), outcomes other than passing
(``harness.errors``) and signals (``harness.interrupts``). Below ``conformance`` and
``fuzz``, which never import each other; above the judge."""
