"""Driving ``mcp-conform`` under faults: a run watched line by line, nodes killed on cue,
the processes of a run found by an environment mark (they inherit it), reports checked."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcp_conform.conformance.report import validate_json
from tests.conformance.runner_helpers import ROOT

CASE_PREFIXES = ("PASSED", "FAILED", "INFO", "SKIPPED", "WARNED", "ERROR")
SILENCE_RULES = {"MCP-ACK-4", "MCP-ACK-5", "MCP-ACK-6", "MCP-ROB-1", "MCP-ROB-2", "MCP-ROB-3",
                 "MCP-ROB-4", "MCP-DUP-1"}
MARK = "MCP_CONFORM_TEST_RUN"


def env(mark: str | None = None) -> dict[str, str]:
    e = dict(os.environ, PYTHONPATH=str(ROOT), NO_COLOR="1", PYTHONUNBUFFERED="1")
    if mark:
        e[MARK] = mark
    return e


def new_mark() -> str:
    return uuid.uuid4().hex


def marked_pids(mark: str) -> list[int]:
    """Every live process carrying ``mark`` in its environment (a run's whole tree)."""
    needle = f"{MARK}={mark}".encode()
    out = []
    for name in os.listdir("/proc"):
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/environ", "rb") as f:
                if needle not in f.read().split(b"\0"):
                    continue
            with open(f"/proc/{name}/stat", "rb") as f:
                state = f.read().rsplit(b")", 1)[1].split()[0]
        except OSError:
            continue
        if state != b"Z":  # a zombie is dead, waiting for its parent to reap it
            out.append(int(name))
    return out


def children(pid: int, needle: str) -> list[int]:
    """Direct children of ``pid`` whose command line contains ``needle``."""
    out = []
    for name in os.listdir("/proc"):
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/stat", "rb") as f:
                ppid = int(f.read().rsplit(b")", 1)[1].split()[1])
            with open(f"/proc/{name}/cmdline", "rb") as f:
                cmd = f.read().replace(b"\0", b" ").decode(errors="replace")
        except (OSError, ValueError):
            continue
        if ppid == pid and needle in cmd:
            out.append(int(name))
    return out


@dataclass
class WatchedRun:
    """``python -m mcp_conform.conformance ARGS``, its stdout lines timestamped as they arrive."""

    args: list[str]
    mark: str | None = None
    lines: list[tuple[float, str]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.proc = subprocess.Popen([sys.executable, "-m", "mcp_conform.conformance", *self.args], cwd=ROOT,
                                     env=env(self.mark), stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True)
        self._cond = threading.Condition()
        self.stderr = ""
        threading.Thread(target=self._read, daemon=True).start()
        threading.Thread(target=self._read_err, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with self._cond:
                self.lines.append((time.monotonic(), line.rstrip("\n")))
                self._cond.notify_all()

    def _read_err(self) -> None:
        assert self.proc.stderr is not None
        self.stderr = self.proc.stderr.read()

    def wait_line(self, pred: Any, timeout: float) -> tuple[float, str]:
        deadline = time.monotonic() + timeout
        i = 0
        with self._cond:
            while True:
                while i < len(self.lines):
                    if pred(self.lines[i][1]):
                        return self.lines[i]
                    i += 1
                left = deadline - time.monotonic()
                if left <= 0 or (self.proc.poll() is not None and i >= len(self.lines)):
                    raise AssertionError(f"no such line within {timeout} s:\n" + self.text())
                self._cond.wait(min(left, 0.1))

    def finish(self, timeout: float = 120.0) -> int:
        try:
            return self.proc.wait(timeout=timeout)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
                self.proc.wait()
            time.sleep(0.1)  # the readers drain

    def text(self) -> str:
        return "\n".join(ln for _, ln in self.lines) + "\n--- stderr ---\n" + self.stderr

    def case_lines_after(self, t: float) -> list[tuple[float, str]]:
        return [(ts, ln) for ts, ln in self.lines if ts > t and ln.startswith(CASE_PREFIXES)]


def case_line(case_id: str) -> Any:
    return lambda ln: ln.startswith(CASE_PREFIXES) and f" {case_id} " in ln


def read_report(path: Path) -> dict[str, Any]:
    doc = json.loads(path.read_text())
    validate_json(doc)
    return dict(doc)


def read_mcap(path: Path) -> int:
    """Messages in an MCAP file, read with CRC validation (raises if unreadable)."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        return sum(1 for _ in make_reader(f, validate_crcs=True).iter_messages())


def kill(pid: int, sig: int = signal.SIGKILL) -> float:
    """Signal ``pid``; the monotonic time it was sent."""
    t = time.monotonic()
    os.kill(pid, sig)
    return t
