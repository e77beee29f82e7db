"""The nested pytest session of a simulated run (sim.suite): the runner's cases and nothing of
the directory it runs in. Its cases are named by package (``--pyargs``), so pytest looked for
``conftest.py`` in the working directory and its ``test*`` folders: run from this repository,
every simulated run loaded the test suite's own tests/conftest.py into the runner's session."""

from __future__ import annotations

import os

from mcp_conform.sim.runner import run_cases


def test_a_simulated_run_loads_no_conftest_of_the_working_directory(tmp_path, monkeypatch):
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "conftest.py").write_text("raise RuntimeError('a conftest of the working directory')\n")
    (tmp_path / "conftest.py").write_text("raise RuntimeError('a conftest of the working directory')\n")
    monkeypatch.chdir(tmp_path)
    run = run_cases(None, seed=1, select=["MCP-HDR-1"])
    assert run.rc == 0 and run.report["error"] is None, run.explain()
    assert run.cases() and set(run.cases().values()) == {"passed"}, run.cases()


def test_the_plugin_autoload_is_as_it_was_after_a_run(monkeypatch):
    monkeypatch.delenv("PYTEST_DISABLE_PLUGIN_AUTOLOAD", raising=False)
    run_cases(None, seed=1, select=["MCP-HDR-1"])
    assert "PYTEST_DISABLE_PLUGIN_AUTOLOAD" not in os.environ
