"""The runner's report files (``--mcp-json``, ``--mcp-junit``, ``--mcp-html``, a baseline
written, ``--mcp-capture``): written at the end of a run by the one process that ran it, or,
under pytest-xdist, by the controller from what each worker handed it (one JSON report, one
JUnit file, one capture merged by ``traceio.merge``), so that a split run reports as a run
without workers would. A report that cannot be written is one line (exit 2); the others are
written all the same. The hooks that call these are ``conformance._plugin_run``'s.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from mcp_conform.conformance._run_state import McpState
from mcp_conform.conformance.baseline import write_baseline
from mcp_conform.conformance.junit import write_junit
from mcp_conform.conformance.report import (
    RunRecord,
    build_json,
    merge_json,
    run_from_json,
    write_json,
)

__all__ = ["hand_to_controller", "merge_worker_reports", "write_reports", "write_run_html", "write_run_reports"]


def write_run_html(path: str, doc: dict[str, Any], capture: str | None) -> None:
    """--mcp-html: the report with each failed case's traffic charted (reports.html)."""
    from mcp_conform.reports.html import write_run

    write_run(path, doc, capture)



def write_reports(writers: list[tuple[str | None, Callable[[str], Any]]]) -> list[str]:
    """Write each report that has a path; one problem line per report that could not be
    written (the others are written all the same)."""
    problems = []
    for path, write in writers:
        if path:
            try:
                write(path)
            except OSError as exc:
                problems.append(str(exc))
    return problems


def write_run_reports(state: McpState, run: RunRecord) -> list[str]:
    """A run without workers: its report files; one problem line per file not written."""
    writers: list[tuple[str | None, Callable[[str], Any]]] = [
        (state.cfg.json_path, lambda p: write_json(p, run)),
        (None if state.list_mode else state.cfg.junit_path, lambda p: write_junit(p, run, state.junit_family)),
        (None if state.list_mode or run.error else state.write_baseline_path,
         lambda p: write_baseline(p, run.cases, run.target)),
        (None if state.list_mode else state.html_path, lambda p: write_run_html(
            p, build_json(run), state.cfg.capture or state.html_capture)),
    ]
    problems = write_reports(writers)
    if state.html_capture:
        Path(state.html_capture).unlink(missing_ok=True)
    return problems


def hand_to_controller(session: pytest.Session, state: McpState, run: RunRecord) -> None:
    """A pytest-xdist worker: its report and its capture part go to the controller (the
    ``workeroutput`` channel pytest-cov uses for its data), which writes the files."""
    wo = session.config.workeroutput  # type: ignore[attr-defined]
    wo["mcp_report"] = build_json(run)
    if state.cfg.capture or state.html_capture:
        wo["mcp_capture_part"] = state.cfg.capture or state.html_capture
        wo["mcp_capture_temporary"] = not state.cfg.capture


def merge_worker_reports(session: pytest.Session, state: McpState | None) -> None:
    """Under pytest-xdist the controller writes ONE JSON report, ONE JUnit file and ONE
    capture from what the workers sent, prints the mcp summary once, and exits as a run
    without workers would."""
    if state is None or not state.worker_docs:
        return
    doc = merge_json(state.worker_docs)
    run = state.merged_run = run_from_json(doc)
    writers: list[tuple[str | None, Callable[[str], Any]]] = [
        (state.cfg.json_path, lambda p: Path(p).write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")),
        (state.cfg.junit_path, lambda p: write_junit(p, run, state.junit_family)),
        (None if run.error else state.write_baseline_path, lambda p: write_baseline(p, run.cases, run.target)),
    ]
    if state.cfg.capture and state.capture_parts:
        from mcp_conform.traceio.merge import merge_captures

        writers.append((state.cfg.capture, lambda p: merge_captures(sorted(state.capture_parts), p)))
    elif state.html_path and state.capture_parts:  # the workers recorded for the HTML report only
        from mcp_conform.traceio.merge import merge_captures

        fd, state.html_capture = tempfile.mkstemp(prefix="mcp-conform-", suffix=".mcap")
        os.close(fd)
        writers.append((state.html_capture, lambda p: merge_captures(sorted(state.capture_parts), p)))
    writers.append((state.html_path, lambda p: write_run_html(p, doc, state.cfg.capture or state.html_capture)))
    problems = write_reports(writers)
    if not state.cfg.capture:  # temporary recordings made only for the HTML report
        for part in [*state.capture_parts, state.html_capture or ""]:
            if part:
                Path(part).unlink(missing_ok=True)
    code = 2 if problems else run.exit_code()
    if code == 0 and session.exitstatus == pytest.ExitCode.TESTS_FAILED:
        code = 1
    for p in problems:
        print(f"error: {p}", file=sys.stderr)
    session.exitstatus = code
