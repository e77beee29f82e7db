"""The floors of the house (docs/architecture.md), held by import-linter's contracts in
pyproject.toml: the tree keeps them, and a deliberately added upward import or circle breaks
them (so the contracts can fail)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("spec", "vehicle", "traceio", "judge", "harness", "reports", "reference_impl",
            "conformance", "fuzz", "captures", "soak", "sim")

#: the one import package (pyproject.toml); the folders above are its subpackages
NAMESPACE = "mcp_conform"

pytest.importorskip("importlinter", reason="import-linter is not installed (pip install -e '.[test]')")


def _lint(root: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", "import sys; from importlinter.cli import lint_imports_command as c; "
         "sys.exit(c.main(args=['pyproject.toml', '--no-cache'], standalone_mode=False))"],
        cwd=root, env={"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin"},
        capture_output=True, text=True, timeout=120)


@pytest.fixture(scope="module")
def tree(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of the packages and pyproject.toml, to break on purpose."""
    root = tmp_path_factory.mktemp("tree")
    shutil.copy(ROOT / "pyproject.toml", root / "pyproject.toml")
    (root / NAMESPACE).mkdir()
    shutil.copy(ROOT / NAMESPACE / "__init__.py", root / NAMESPACE / "__init__.py")
    for p in PACKAGES:
        shutil.copytree(ROOT / p, root / p, ignore=shutil.ignore_patterns("__pycache__", "golden"))
        (root / NAMESPACE / p).symlink_to(Path("..") / p)  # as the checkout holds them
    return root


def test_the_tree_keeps_every_contract(tree: Path) -> None:
    r = _lint(tree)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "BROKEN" not in r.stdout and "KEPT" in r.stdout


@pytest.mark.parametrize(("module", "line", "contract"), [
    ("spec/about.py", "import mcp_conform.judge.monitor", "Layers"),
    ("judge/attribution.py", "import mcp_conform.harness.driver", "Layers"),
    ("traceio/trace.py", "from mcp_conform.judge import monitor", "Layers"),
    ("fuzz/findings.py", "import mcp_conform.conformance.report", "Layers"),
    ("conformance/baseline.py", "import mcp_conform.fuzz.findings", "Layers"),
    ("captures/show.py", "import mcp_conform.reference_impl.endpoint", "reference node"),
    ("judge/_monitor_base.py", "import mcp_conform.judge.monitor", "circles"),
])
def test_an_added_upward_import_or_circle_breaks_a_contract(tree: Path, module: str, line: str,
                                                           contract: str) -> None:
    path = tree / module
    original = path.read_text()
    try:
        path.write_text(original + f"\n{line}  # added by the test\n")
        r = _lint(tree)
    finally:
        path.write_text(original)
    assert r.returncode == 1, r.stdout + r.stderr
    broken = r.stdout[r.stdout.index("Broken contracts"):]
    assert contract in broken, broken


def test_docs_architecture_names_every_package_of_the_contracts() -> None:
    """docs/architecture.md draws the same floors the contracts hold."""
    tomllib = pytest.importorskip("tomllib", reason="Python < 3.11 has no tomllib")
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    doc = (ROOT / "docs" / "architecture.md").read_text()
    assert config["root_packages"] == [NAMESPACE]
    (layers,) = [c["layers"] for c in config["contracts"] if c["type"] == "layers"]
    floors = [[p.strip() for p in layer.split("|")] for layer in layers]
    assert sorted(p for f in floors for p in f) == sorted(PACKAGES)
    for p in PACKAGES:  # one paragraph each (index raises when it is missing)
        doc.index(f"**`{p}`**")
    picture = doc[:doc.index("## The packages")]
    heights = {p: picture.index(f" {p} ") if f" {p} " in picture else picture.index(p)
               for p in PACKAGES}
    for upper, lower in zip(floors, floors[1:], strict=False):  # the floors top to bottom
        assert max(heights[p] for p in upper) < min(heights[p] for p in lower), (upper, lower)


def _bench_imports(bench: Path) -> dict[str, set[str]]:
    """Each bench script's imports: module name -> the top-level names it imports (at any depth
    of its body: the imports inside functions count)."""
    import ast

    out: dict[str, set[str]] = {}
    for path in sorted(bench.glob("*.py")):
        names: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, ast.Import):
                names |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                names.add(node.module.split(".")[0])
        out[path.stem] = names
    return out


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """A cycle of ``graph`` (a list of its nodes, first repeated last), or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        state[n] = 1
        stack.append(n)
        for m in sorted(graph.get(n, ())):
            if state.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m in graph and not state.get(m):
                found = visit(m)
                if found:
                    return found
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if not state.get(n):
            found = visit(n)
            if found:
                return found
    return None


def test_bench_imports_the_namespace_only_and_has_no_circle() -> None:
    """Issue 37: no import circle, bench/ included (import-linter sees the package, not the
    scripts beside it): the bench scripts import each other without a circle, and ours only
    through ``mcp_conform`` (never a bare ``spec`` or ``harness``)."""
    imports = _bench_imports(ROOT / "bench")
    graph = {m: {n for n in names if n in imports} for m, names in imports.items()}
    assert _cycle(graph) is None, _cycle(graph)
    bare = {m: sorted(names & set(PACKAGES)) for m, names in imports.items() if names & set(PACKAGES)}
    assert not bare, bare


def test_the_cycle_finder_finds_a_cycle() -> None:
    """(The check above can fail.)"""
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None
