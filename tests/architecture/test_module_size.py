"""Modules that read in one sitting (issue 17): no module of the packages or the tools beside
them is over 600 lines; a larger one is split along a seam of its own (the records a capture
is read as, the channels a capture is written in, a judgement's parameters, a run's report
files), not by moving its tail."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
LIMIT = 600


def _modules(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*.py")
                  if not {".git", "tests", ".tox", ".venv", "build"} & set(p.relative_to(root).parts))


def _lines(path: Path) -> int:
    with path.open("rb") as f:
        return sum(1 for _ in f)


def test_no_module_is_over_600_lines() -> None:
    modules = _modules(ROOT)
    assert len(modules) > 50  # the tree was found (not an empty glob)
    over = {str(p.relative_to(ROOT)): n for p in modules if (n := _lines(p)) > LIMIT}
    assert not over, f"modules over {LIMIT} lines: {over}"
