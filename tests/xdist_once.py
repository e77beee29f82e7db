"""Make an expensive test input once per test session, also under pytest-xdist.

Under pytest-xdist a module- or session-scoped fixture is built once per worker that runs one
of its tests: a campaign, a build or a recorded run used by tests spread over three workers is
made three times (issue 38: CI's slow run). ``once(tmp_path_factory, name, make)`` makes it
once: ``make(directory)`` writes its files in an empty directory and returns what the tests
need (JSON-able data; ``Path`` values are kept as paths), and

- under xdist the first worker to ask makes it in a directory of the session's base directory
  (``pytest-N``, shared by every worker and new each session) under an fcntl lock; the others
  wait for the lock and read the stored result;
- without xdist it is made in a directory of this process's own.

A making that raised (an assert, a skip) stores nothing: the next worker to ask makes it again,
in a new directory, and fails or skips there too. The result is read back from its JSON in
both cases, so a test sees the same types (tuples as lists) with and without xdist.

What is made is shared: a test must treat its files as read-only (copy them to its own
``tmp_path`` to change them); only files and data can be shared, never a live process.
"""

from __future__ import annotations

import fcntl
import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

_PATH = "__path__"


def _encode(value: Any) -> Any:
    if isinstance(value, Path):
        return {_PATH: str(value)}
    if isinstance(value, dict):
        return {str(k): _encode(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_encode(v) for v in value]
    return value


def _decode(value: Any) -> Any:
    if isinstance(value, dict):
        if set(value) == {_PATH}:
            return Path(value[_PATH])
        return {k: _decode(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_decode(v) for v in value]
    return value


def _roundtrip(value: Any) -> Any:
    return _decode(json.loads(json.dumps(_encode(value))))


def session_dir(tmp_path_factory: pytest.TempPathFactory) -> Path | None:
    """The directory every xdist worker of this session shares (the controller's base
    directory, ``pytest-N``, parent of each worker's ``popen-gwN``), or None without xdist."""
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER") and base.name.startswith("popen-gw"):
        return base.parent
    return None


def once(tmp_path_factory: pytest.TempPathFactory, name: str, make: Callable[[Path], Any]) -> Any:
    """``make(directory)``'s result, made once per test session (see the module's docstring);
    ``name`` names it among the session's shared results (one name, one making)."""
    shared = session_dir(tmp_path_factory)
    if shared is None:
        return _roundtrip(make(tmp_path_factory.mktemp(name)))
    home = shared / f"once-{name}"
    home.mkdir(exist_ok=True)
    with open(home / "lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when closed, also if make() raises
        done = home / "done.json"
        if not done.exists():
            attempt = Path(tempfile.mkdtemp(dir=home))
            result = json.dumps(_encode(make(attempt)))
            tmp = home / "done.json.tmp"
            tmp.write_text(result)
            tmp.replace(done)
        return _decode(json.loads(done.read_text()))
