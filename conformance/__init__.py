"""conformance: the black-box runner behind ``mcp-conform`` — the pytest plugin
(``conformance.plugin``, ``conformance._plugin_run``), the cases (``conformance.cases``,
``conformance.cases_manager``) and their contexts with the verify helpers
(``conformance.drone_case``, ``conformance.manager_case``), reports (``conformance.report``),
baselines, and the command line. Drives the node through ``harness``; never imports
``fuzz`` or ``reference_impl``."""
