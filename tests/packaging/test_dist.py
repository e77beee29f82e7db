"""The package as it would be published (issue 40 item 3): ``python -m build`` makes the
sdist from a copy of the tree as git has it, then the wheel from that sdist; ``twine check``
passes both; the sdist holds every file git tracks and its own tests pass unpacked; the wheel
holds every file the code refers to; and, installed into a fresh virtual environment,
``mcp-conform`` passes against its embedded reference node from a folder outside the checkout,
its report and ``--version`` saying the wheel's version.

The build runs without isolation (``--no-isolation``: the test extra brings setuptools>=77, so
no package index is needed); the venv (``--without-pip``) gets the wheel alone, from this
interpreter's pip (``--python VENV``, ``--no-deps --no-index``), and finds
its dependencies in this interpreter's site-packages, named by a ``.pth`` file."""

from __future__ import annotations

import importlib.util
import json
import os
import re
import shutil
import site
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pytest

from mcp_conform.spec.about import DIST_NAME, __version__
from tests.packaging.tree import NAMESPACE, ROOT, module_paths, resource_paths, top_packages
from tests.xdist_once import once

pytestmark = pytest.mark.slow

#: the sdist's own tests run from the unpacked tree: a few quick files (~5 s) that read the
#: tree: the spec and its generated docs/ pages, the version pyproject.toml reads, --help
SDIST_TESTS = (
    "tests/spec/test_load.py",
    "tests/spec/test_codec.py",
    "tests/spec/test_docs.py",
    "tests/packaging/test_version.py",
)
#: files git tracks that the sdist leaves out
NOT_IN_SDIST = {".gitignore"}


def _tracked() -> list[str] | None:
    """The tree's files as a fresh clone would have them (those git tracks: a new file counts
    once it is added), or None outside a git checkout (an unpacked sdist)."""
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        return None
    proc = subprocess.run(
        ["git", "ls-files", "-z", "--cached"], cwd=ROOT, capture_output=True, text=True, timeout=60
    )
    if proc.returncode != 0:
        return None
    return sorted(f for f in proc.stdout.split("\0") if f and (ROOT / f).is_file())


def _run(
    argv: list[str], *, cwd: Path, env: dict[str, str] | None = None, timeout: float = 300
) -> str:
    proc = subprocess.run(
        argv,
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
    )
    assert proc.returncode == 0, (
        f"{' '.join(map(str, argv))} exited {proc.returncode}:\n"
        f"{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    )
    return proc.stdout


def _venv(venv: Path, tmp_path: Path) -> tuple[Path, dict[str, str]]:
    """A fresh venv with no pip of its own that finds this interpreter's packages (the
    dependencies) after its own: its bin folder, and the environment to run it in."""
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)], cwd=tmp_path, timeout=120)
    bin_ = venv / "bin"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env["NO_COLOR"] = "1"
    # the dependencies, from this interpreter's site-packages (this one may itself be a venv,
    # tox's: --system-site-packages would see its base's), after the venv's own: a directory
    # named in a .pth is not a site directory, so its .pth files (an editable install of this
    # checkout among them) do not run in the venv...
    purelib = _run(
        [str(bin_ / "python"), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        cwd=tmp_path,
        env=env,
    ).strip()
    # ... less this checkout's own install (its metadata names the pytest plugin entry point)
    dirs = []
    for i, sp in enumerate(site.getsitepackages()):
        deps = tmp_path / f"deps{i}"
        deps.mkdir()
        for entry in Path(sp).iterdir() if Path(sp).is_dir() else ():
            if not entry.name.startswith(("centmesh_mcp_conform", "__editable__")):
                (deps / entry.name).symlink_to(entry)
        dirs.append(str(deps))
    (Path(purelib) / "zz-deps.pth").write_text("\n".join(dirs) + "\n")
    return bin_, env


def _install(wheel: Path, bin_: Path, cwd: Path, env: dict[str, str]) -> None:
    """The wheel alone, by this interpreter's pip (--python: no pip of the venv's own to
    install, and pip sees no other copy of the distribution there)."""
    _run([sys.executable, "-m", "pip", "--python", str(bin_ / "python"), "install", "-q",
          "--no-deps", "--no-index", "--disable-pip-version-check", str(wheel)], cwd=cwd, env=env)


@pytest.fixture(scope="module")
def dists(tmp_path_factory) -> dict[str, Path]:
    """The tree copied as git has it, its sdist, and the wheel built from that sdist: built once
    per test session (tests/xdist_once.py; CI's slow run built them on two workers), read-only."""
    for module, why in (("build", "build"), ("twine", "twine"), ("setuptools", "setuptools>=77")):
        if importlib.util.find_spec(module) is None:
            pytest.skip(f"{why} is not installed (pip install -e '.[test]')")
    return once(tmp_path_factory, "dist", _build)


def _build(base: Path) -> dict[str, Path]:
    src = base / "src"
    files = _tracked()
    if files is None:
        shutil.copytree(
            ROOT,
            src,
            ignore=shutil.ignore_patterns(
                "__pycache__", "*.pyc", "build", "dist", "*.egg-info", ".tox", ".*_cache"
            ),
        )
    else:
        for f in files:
            (src / f).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / f, src / f)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    _run(
        [sys.executable, "-m", "build", "--no-isolation", "--outdir", str(base / "out"), str(src)],
        cwd=base,
        env=env,
    )
    (sdist,) = (base / "out").glob("*.tar.gz")
    (wheel,) = (base / "out").glob("*.whl")
    return {"base": base, "sdist": sdist, "wheel": wheel}


def test_the_sdist_holds_every_file_git_tracks(dists):
    tracked = _tracked()
    if tracked is None:
        pytest.skip("not a git checkout: no list of the tree's files to compare with")
    with tarfile.open(dists["sdist"]) as tar:
        names = {n.split("/", 1)[1] for n in tar.getnames() if "/" in n}
    missing = sorted(set(tracked) - names - NOT_IN_SDIST)
    assert not missing, f"MANIFEST.in leaves out {len(missing)} tracked file(s): {missing[:20]}"
    assert not [n for n in names if "__pycache__" in n or n.endswith(".pyc")]


def test_the_wheel_holds_every_file_the_code_refers_to(dists):
    with zipfile.ZipFile(dists["wheel"]) as z:
        every = set(z.namelist())
    # one import namespace (issue 37): nothing of ours at the top of site-packages
    bare = sorted(n for n in every if not n.startswith((f"{NAMESPACE}/", ".dist-info/"))
                  and ".dist-info/" not in n)
    assert not bare, f"the wheel installs outside {NAMESPACE}/: {bare[:10]}"
    names = {n.removeprefix(f"{NAMESPACE}/") for n in every}
    missing = []
    for owner, rel in sorted(module_paths().items()):
        source = ROOT / rel
        wanted = (
            [
                p.relative_to(ROOT).as_posix()
                for p in source.rglob("*")
                if p.is_file() and "__pycache__" not in p.parts
            ]
            if source.is_dir()
            else [rel]
        )
        missing += [f"{owner}: {w}" for w in wanted if w not in names]
    missing += [f"importlib.resources: {r}" for r in sorted(resource_paths()) if r not in names]
    assert not missing, "the code refers to what the wheel does not ship:\n" + "\n".join(missing)
    # and every package is there, with its marker of inline types
    for pkg in top_packages():
        assert f"{pkg}/__init__.py" in names and f"{pkg}/py.typed" in names, pkg
    assert not [n for n in names if n.startswith(("tests/", "docs/", "examples/", "bench/"))]


@pytest.mark.timeout(900)  # a bound for a loaded host (48 s quiet; over 300 s at load 30, CI run 5)
def test_the_sdist_tests_itself_and_the_wheel_runs_outside_the_checkout(dists, tmp_path):
    base, sdist, wheel = dists["base"], dists["sdist"], dists["wheel"]
    assert wheel.name.startswith(f"{DIST_NAME.replace('-', '_')}-{__version__}-"), wheel.name
    _run(
        [sys.executable, "-m", "twine", "check", "--strict", str(sdist), str(wheel)],
        cwd=base,
        timeout=120,
    )

    # the sdist's own tests, from the unpacked tree and its code (PYTHONPATH), nothing else's
    with tarfile.open(sdist) as tar:
        tar.extractall(
            tmp_path / "sdist", **({"filter": "data"} if hasattr(tarfile, "data_filter") else {})
        )
    (tree,) = (tmp_path / "sdist").iterdir()
    # (not MCP_TEST_CPU/MCP_TEST_RUNS: those tests' CPU is this test's own, its child's)
    env = {k: v for k, v in os.environ.items() if k not in ("MCP_TEST_CPU", "MCP_TEST_RUNS")}
    env.update(PYTHONPATH=str(tree), NO_COLOR="1")
    where = _run(
        [
            sys.executable,
            "-c",
            "import mcp_conform.spec as s, mcp_conform.conformance as c; print(s.__file__); print(c.__file__)",
        ],
        cwd=tree,
        env=env,
    )
    assert all(Path(p).is_relative_to(tree) for p in where.split()), where
    # 600 s: a bound for a loaded host (CI run 33, load ~30: over 300 s), inside the test's 900
    out = _run(
        [sys.executable, "-m", "pytest", "-q", "-m", "not slow", *SDIST_TESTS], cwd=tree, env=env, timeout=600
    )
    assert re.search(r"\d+ passed", out) and " failed" not in out and " error" not in out, out[
        -2000:
    ]

    # the wheel in a fresh venv, run from a folder outside the checkout
    venv, away = tmp_path / "venv", tmp_path / "away"
    away.mkdir()
    bin_, env = _venv(venv, tmp_path)
    _install(wheel, bin_, away, env)
    where = _run(
        [
            str(bin_ / "python"),
            "-c",
            "import importlib.metadata as m; from mcp_conform import spec, conformance, reference_impl, traceio; "
            f"print(m.version({DIST_NAME!r})); "
            "print(spec.__file__, conformance.__file__, reference_impl.__file__, traceio.__file__)",
        ],
        cwd=away,
        env=env,
    )
    installed, *files = where.split()
    assert installed == __version__, where
    assert all(Path(f).is_relative_to(venv) for f in files), f"the venv runs another copy: {files}"

    version = _run([str(bin_ / "mcp-conform"), "--version"], cwd=away, env=env)
    assert version.startswith(f"mcp-conform {__version__}"), version
    out = _run([str(bin_ / "mcp-conform"), "--json", "report.json"], cwd=away, env=env, timeout=240)
    doc = json.loads((away / "report.json").read_text())
    assert doc["tool"]["version"] == __version__, doc["tool"]
    summary = re.search(
        r"(\d+) passed, (\d+) failed, \d+ warned, \d+ skipped, \d+ info, (\d+) error", out
    )
    assert summary and int(summary[1]) > 0 and summary[2] == "0" and summary[3] == "0", out[-2000:]


#: a user's own top-level packages, named as our folders are (issue 37: no serious library
#: ships ``import spec``), and a test of theirs that imports them
USER_PACKAGES = ("spec", "harness", "reports")
USER_TEST = """
import harness
import reports
import spec


def test_my_packages():
    assert (spec.WHO, harness.WHO, reports.WHO) == ("user", "user", "user")
"""
USER_CONFTEST = """
import sys


def pytest_sessionfinish(session):
    ours = sorted(m for m in sys.modules if m.split(".")[0] == "mcp_conform")
    with open("loaded.txt", "w") as f:
        f.write(" ".join(ours))
"""


def test_a_users_own_spec_harness_and_reports_and_ours_all_import(dists, tmp_path):
    """A venv that already holds packages named ``spec``, ``harness`` and ``reports``: after our
    wheel is installed, both theirs and ours import, and the user's pytest run is unchanged (the
    same outcome; our pytest plugin loads nothing of the runner in it)."""
    venv, project = tmp_path / "venv", tmp_path / "project"
    project.mkdir()
    bin_, env = _venv(venv, tmp_path)
    purelib = Path(_run([str(bin_ / "python"), "-c",
                         "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                        cwd=tmp_path, env=env).strip())
    for name in USER_PACKAGES:
        (purelib / name).mkdir()
        (purelib / name / "__init__.py").write_text('WHO = "user"\n')
    (project / "test_mine.py").write_text(USER_TEST)
    (project / "conftest.py").write_text(USER_CONFTEST)

    def users_run() -> tuple[str, str]:
        out = _run([str(bin_ / "python"), "-m", "pytest", "-q", "-p", "no:cacheprovider",
                    "-p", "no:randomly"], cwd=project, env=env)
        (summary,) = re.findall(r"^\d+ passed.*$", out, re.M)
        return re.sub(r" in [\d.]+s.*", "", summary), (project / "loaded.txt").read_text()

    before = users_run()
    _install(dists["wheel"], bin_, project, env)
    after = users_run()
    assert before[0] == after[0] == "1 passed", (before, after)
    assert "mcp_conform.spec" not in after[1].split(), after[1]  # the plugin stayed inert
    where = _run([str(bin_ / "python"), "-c",
                  "import spec, harness, reports, mcp_conform.spec as s, mcp_conform.harness as h, "
                  "mcp_conform.reports as r; print(spec.WHO, harness.WHO, reports.WHO); "
                  "print(s.__file__, h.__file__, r.__file__, s.SPEC.version)"],
                 cwd=project, env=env)
    theirs, ours = where.splitlines()
    assert theirs == "user user user", where
    *files, version = ours.split()
    assert all(Path(f).is_relative_to(purelib / "mcp_conform") for f in files), where
    assert version, where
