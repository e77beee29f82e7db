"""The manager-role conformance cases (``mcp-conform --role manager``), one module per rule
group. The runner plays the drones (``harness.drone_players``); each case judges the
recorded mission through one verify helper of the ``node`` fixture
(``conformance.manager_case.ManagerCaseContext``)."""
