"""tests/xdist_once.py: a result made once per session, shared by xdist workers (issue 38)."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from tests.xdist_once import once, session_dir


class _Factory:
    """A worker's tmp_path_factory as xdist makes it: its base directory ``popen-gwN`` in the
    session's ``pytest-N``."""

    def __init__(self, session: Path, worker: str) -> None:
        self.base = session / f"popen-{worker}"
        self.base.mkdir(parents=True, exist_ok=True)

    def getbasetemp(self) -> Path:
        return self.base

    def mktemp(self, name: str) -> Path:  # a worker's own directory: not used under xdist
        raise AssertionError(f"mktemp({name!r}) under xdist")


def test_the_workers_of_a_session_share_one_making(tmp_path, monkeypatch):
    monkeypatch.setenv("PYTEST_XDIST_WORKER", "gw0")
    made: list[Path] = []

    def make(d: Path) -> dict:
        made.append(d)
        (d / "out.txt").write_text("made\n")
        return {"file": d / "out.txt", "pair": (1, "two")}

    workers = [_Factory(tmp_path / "pytest-7", f"gw{n}") for n in range(4)]
    with ThreadPoolExecutor(4) as pool:  # at once, as xdist's workers would ask
        results = list(pool.map(lambda f: once(f, "thing", make), workers))
    assert len(made) == 1 and made[0].parent == tmp_path / "pytest-7" / "once-thing", made
    assert all(r == {"file": made[0] / "out.txt", "pair": [1, "two"]} for r in results), results
    assert isinstance(results[3]["file"], Path) and results[3]["file"].read_text() == "made\n"
    # another name is another making; another session (pytest-8) makes its own
    assert once(workers[1], "other", lambda d: 5) == 5
    assert once(_Factory(tmp_path / "pytest-8", "gw0"), "thing", make)["file"].parent == made[1]
    assert session_dir(workers[2]) == tmp_path / "pytest-7"


def test_a_making_that_failed_is_made_again_by_the_next(tmp_path, monkeypatch):
    monkeypatch.setenv("PYTEST_XDIST_WORKER", "gw1")
    calls: list[Path] = []

    def make(d: Path) -> str:
        calls.append(d)
        assert len(calls) > 1, "the first making fails"
        return "ok"

    a, b = _Factory(tmp_path / "pytest-3", "gw0"), _Factory(tmp_path / "pytest-3", "gw1")
    with pytest.raises(AssertionError, match="the first making fails"):
        once(a, "flaky", make)
    assert once(b, "flaky", make) == "ok" and once(a, "flaky", make) == "ok"
    assert len(calls) == 2 and calls[0] != calls[1]  # a new directory for the second making


def test_without_xdist_it_is_made_in_the_process_own_directory(tmp_path_factory, monkeypatch):
    monkeypatch.delenv("PYTEST_XDIST_WORKER", raising=False)
    got = once(tmp_path_factory, "local", lambda d: [d, (d / "x").exists()])
    assert session_dir(tmp_path_factory) is None
    assert got[0].is_dir() and got[0].is_relative_to(tmp_path_factory.getbasetemp()) and got[1] is False
