"""Modules that read in one sitting (issue 17): no module of the packages or the tools beside
them is over 600 lines; a larger one is split along a seam of its own (the records a capture
is read as, the channels a capture is written in, a judgement's parameters, a run's report
files), not by moving its tail.

The modules are the tracked ones (``git ls-files``), not every ``.py`` on the disk: a
newcomer's virtual environment inside the checkout, whatever its name, is not ours (issue 37).
Without git (an unpacked sdist) the tree is walked, skipping every directory that holds a
``pyvenv.cfg`` or is a ``site-packages``."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
LIMIT = 600
#: Directories that are never ours to measure, tracked or not.
SKIP = {".git", "tests", ".tox", ".venv", "build", "site-packages", "__pycache__"}


def _tracked(root: Path) -> list[Path] | None:
    """The ``.py`` files git tracks below ``root``; None without git or outside a checkout."""
    try:
        r = subprocess.run(["git", "ls-files", "-z", "--", "*.py"], cwd=root,
                           capture_output=True, timeout=60, check=False)
    except (OSError, subprocess.TimeoutExpired):
        return None
    if r.returncode != 0:
        return None
    return [root / name for name in r.stdout.decode().split("\0") if name]


def _walked(root: Path) -> list[Path]:
    """Every ``.py`` below ``root`` outside virtual environments and :data:`SKIP`."""
    found = []
    for here, dirs, files in os.walk(root):
        dirs[:] = [d for d in dirs
                   if d not in SKIP and not (Path(here) / d / "pyvenv.cfg").exists()]
        found += [Path(here) / f for f in files if f.endswith(".py")]
    return found


def _modules(root: Path) -> list[Path]:
    paths = _tracked(root)
    if paths is None:
        paths = _walked(root)
    return sorted(p for p in paths
                  if p.is_file() and not SKIP & set(p.relative_to(root).parts[:-1]))


def _lines(path: Path) -> int:
    with path.open("rb") as f:
        return sum(1 for _ in f)


def _over(root: Path) -> dict[str, int]:
    return {str(p.relative_to(root)): n for p in _modules(root) if (n := _lines(p)) > LIMIT}


def test_no_module_is_over_600_lines() -> None:
    assert len(_modules(ROOT)) > 50  # the tree was found (not an empty list)
    over = _over(ROOT)
    assert not over, f"modules over {LIMIT} lines: {over}"


def _checkout(root: Path) -> None:
    """A package of two modules (one of 700 lines) and a venv under an unusual name holding
    another 700-line module, as a newcomer's ``python -m venv env`` leaves it."""
    (root / "pkg").mkdir()
    (root / "pkg" / "small.py").write_text("x = 1\n")
    (root / "pkg" / "big.py").write_text("x = 1\n" * 700)
    site = root / "env" / "lib" / "python3.10" / "site-packages" / "dep"
    site.mkdir(parents=True)
    (root / "env" / "pyvenv.cfg").write_text("home = /usr/bin\n")
    (site / "huge.py").write_text("y = 2\n" * 700)
    (root / "venv-other" / "dep").mkdir(parents=True)  # a venv whose pyvenv.cfg is all it says
    (root / "venv-other" / "pyvenv.cfg").write_text("home = /usr/bin\n")
    (root / "venv-other" / "dep" / "huge.py").write_text("y = 2\n" * 700)


@pytest.mark.skipif(shutil.which("git") is None, reason="git is not installed")
def test_a_venv_in_a_checkout_is_not_measured_but_a_tracked_module_is(tmp_path: Path) -> None:
    _checkout(tmp_path)
    env = {**os.environ, "GIT_CEILING_DIRECTORIES": str(tmp_path.parent)}
    subprocess.run(["git", "init", "-q"], cwd=tmp_path, env=env, check=True, timeout=60)
    subprocess.run(["git", "add", "pkg"], cwd=tmp_path, env=env, check=True, timeout=60)
    assert _tracked(tmp_path) is not None
    assert _over(tmp_path) == {"pkg/big.py": 700}


def test_without_git_the_walk_skips_every_venv(tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    _checkout(tmp_path)
    monkeypatch.setenv("PATH", str(tmp_path / "no-bin"))  # git is absent
    assert _tracked(tmp_path) is None
    assert [str(p.relative_to(tmp_path)) for p in _modules(tmp_path)] == ["pkg/big.py",
                                                                          "pkg/small.py"]
    assert _over(tmp_path) == {"pkg/big.py": 700}
