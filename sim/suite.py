"""One simulated run of the runner's suite, its pytest session made cheap (issue 38: the quick
tests run several hundred simulated suites). Each entry point of the simulator
(:mod:`sim.runner`, :mod:`sim.manager_runner`, :mod:`sim.vehicle_role`, :mod:`sim.gcs_role`)
runs ``mcp-conform``'s own pytest session, nested, on its virtual clock; what that session
costs besides the cases is paid on every run, and two shares of it serve nobody here:

- pytest's plugin autoload and the conftest files of the directory it runs in: off in every
  run of the suite, simulated or real (``conformance.cli.pytest_args``:
  ``--disable-plugin-autoload`` with the plugin named, ``--noconftest``). Before, each
  ``pytest.main`` walked every installed distribution's entry points, some 25-40 ms a run, and
  run from this repository each nested session loaded ``tests/conftest.py`` (the test suite's
  own hooks, its ``MCP_TEST_CPU`` recorder among them).
- the terminal report. A simulated run is ``--quiet`` (its stdout is /dev/null): the case
  lines and the per-rule table were rendered by rich for nobody, some 15-25 ms a run.
  :class:`SilentTerminal` renders nothing; its errors still go to stderr (``TerminalReport.error``).

- and each run let go of at its end (:func:`_let_go`: ``atexit`` held every run's state).

None of these touches what is judged: the JSON report (cases, outcomes, evidence, monitor verdicts)
is the same, seed for seed (``bench/sim_report_check.py``).
"""

from __future__ import annotations

import atexit
import io
from typing import Any

import pytest
from rich.console import Console

from mcp_conform.conformance.terminal import TerminalReport
from mcp_conform.harness.clock import VirtualClock

__all__ = ["SilentTerminal", "run_suite", "suite_args"]

class SilentTerminal(TerminalReport):
    """The run's live report, rendered for nobody: a simulated run's stdout is /dev/null."""

    def __init__(self) -> None:
        super().__init__(Console(file=io.StringIO(), highlight=False))

    def _print(self, *objs: Any, **kw: Any) -> None:
        return None


def suite_args(ns: Any) -> list[str]:
    """``conformance.cli.pytest_args`` for ``ns``: the session a real run has (isolated: no
    plugin autoload, no conftest; module docstring)."""
    from mcp_conform.conformance import cli

    return cli.pytest_args(ns)


def run_suite(clock: VirtualClock, args: list[str], plugin: Any) -> int:
    """``pytest.main(args)`` with ``plugin`` on ``clock`` (:meth:`VirtualClock.run`), quiet;
    its exit code."""
    from mcp_conform.conformance import cli

    with cli._quiet(True):
        return int(clock.run(lambda: cli.run_pytest(args, [plugin])))


def silence(config: pytest.Config) -> None:
    """The run's terminal report made a :class:`SilentTerminal` (``config``: the nested
    session's), and the run let go of when it ends (:func:`_let_go`)."""
    from mcp_conform.conformance._run_state import state_of

    state = state_of(config)
    if state is not None:
        state._terminal = SilentTerminal()
        config.add_cleanup(lambda: _let_go(state))


def _let_go(state: Any) -> None:
    """The run's state off ``atexit``'s list. ``McpState.start_session`` registers its
    ``close_session`` there (a process killed mid-run still closes its capture) and nothing
    takes it off: in a process that runs many suites each run -- its config, session, cases,
    monitors, link records, some 15,000 objects for a drone run -- stayed reachable to the
    end, every full collection of the garbage collector walked them all again, and a worker
    of the quick tests grew to 600 MB. The session is closed by then (the plugin's
    ``pytest_sessionfinish`` called it); the call is harmless if it was never registered."""
    atexit.unregister(state.close_session)
