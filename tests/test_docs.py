"""The README and the guides in docs/ as a user reads them (issue 40).

- Every command line of ours in a shell block of README.md or docs/**/*.md (and in a ``$ ``
  line of a text block) parses with its tool's own argument parser: an option renamed or
  removed fails here, with the page and the line. Commands nested in ``--spawn`` and soak's
  ``--drone``/``--manager`` strings are parsed too, placeholders filled in.
- The README's failing run fails as the README shows it (a real run against the faulty
  sample node).
- The docs site builds with ``mkdocs build --strict`` (broken links and anchors fail it);
  skipped, with the line that installs it, where MkDocs Material is not installed. A whole
  site build (about 7 CPU s): in the slow tier, not the README's quick run.

The guides' longer sections are run as written in their own tests: tests/test_readme_ci.py
(docs/guide/ci.md), tests/vehicle/test_readme.py (docs/guide/vehicle.md).
"""

from __future__ import annotations

import contextlib
import importlib
import io
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
SEPARATORS = {"&&", "||", "|", ";", "&"}
#: what a placeholder stands for when a nested command line is parsed
PLACEHOLDERS = {"id": "1", "target_host": "127.0.0.1", "target_port": "7890", "listen_host": "127.0.0.1",
                "listen_port": "7889", "broadcast": "127.255.255.255", "mavlink": "tcp:127.0.0.1:5760",
                "drones": "1,2", "challenge": "1", "waypoints": "examples/mission.waypoints",
                "obstacles": "examples/obstacles.waypoints", "rto": "0.2", "record": "record.json",
                "python": sys.executable}
NESTED = ("--spawn", "--drone", "--manager", "--mcp-spawn")


def _scripts() -> dict[str, str]:
    text = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    section = text.split("[project.scripts]", 1)[1].split("\n[", 1)[0]
    return dict(re.findall(r'^([\w-]+)\s*=\s*"([^"]+)"', section, re.M))


SCRIPTS = _scripts()


def _parser_of(words: list[str]):
    """The argparse parser behind a command line of ours, and the arguments it gets."""
    if words[:3] == ["python", "-m", "mcp_conform.vehicle"]:
        return importlib.import_module("mcp_conform.vehicle.cli").build_parser(), words[3:]
    args = words[1:]
    if words[0] == "mcp-node" and "--protocol" in args:
        from mcp_conform.spec.profiles import PROFILES, resolve

        i = args.index("--protocol")
        module = resolve(PROFILES[args[i + 1]].reference_cli)
        return module.build_parser(), args[:i] + args[i + 2:]
    module_name = SCRIPTS[words[0]].split(":")[0]
    for name in (module_name, ".".join(module_name.split(".")[:2]) + ".cli"):
        module = importlib.import_module(name)
        if hasattr(module, "build_parser"):
            return module.build_parser(), args
    raise AssertionError(f"no build_parser for {words[0]} ({module_name})")


def _ours(words: list[str]) -> bool:
    return bool(words) and (words[0] in SCRIPTS or words[:3] == ["python", "-m", "mcp_conform.vehicle"])


def _command_lines(words: list[str]) -> list[list[str]]:
    """The commands of ours in one shell line's words, and those nested in their strings."""
    found, cmd = [], []
    for w in [*words, "&&"]:
        if w not in SEPARATORS:
            cmd.append(w)
            continue
        if _ours(cmd):
            found.append(cmd)
            for opt, value in zip(cmd, cmd[1:], strict=False):
                if opt in NESTED and "..." not in value:
                    filled = re.sub(r"\{(\w+)\}", lambda m: PLACEHOLDERS.get(m.group(1), m.group(0)), value)
                    found += _command_lines(shlex.split(filled))
        cmd = []
    return found


def documented_commands() -> list[tuple[str, list[str]]]:
    out = []
    for page in PAGES:
        for lang, body in re.findall(r"```(\w*)\n(.*?)```", page.read_text(encoding="utf-8"), re.S):
            for line in body.replace("\\\n", " ").splitlines():
                if lang == "text" and line.startswith("$ "):
                    line = line[2:]
                elif lang not in ("sh", "bash"):
                    continue
                for words in _command_lines(shlex.split(line, comments=True)):
                    out.append((f"{page.relative_to(ROOT)}: {' '.join(words)[:120]}", words))
    return out


COMMANDS = documented_commands()


def test_the_pages_hold_the_commands_of_every_tool() -> None:
    """The extraction finds something of each tool (an empty parametrization proves nothing)."""
    tools = {words[0] if words[0] != "python" else "mcp-vehicle" for _, words in COMMANDS}
    assert tools >= {*SCRIPTS, "mcp-vehicle"}, sorted({*SCRIPTS, "mcp-vehicle"} - tools)


@pytest.mark.parametrize("where,words", COMMANDS, ids=[w for w, _ in COMMANDS])
def test_every_documented_command_parses(where: str, words: list[str]) -> None:
    parser, args = _parser_of(words)
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            parser.parse_args(args)
        except SystemExit as exc:
            assert exc.code == 0, f"{where}\n{err.getvalue().strip()}"


def _readme_failing_run() -> tuple[str, str]:
    """The README's failing run: its command, and the output shown under it."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text[text.index("## What a failure looks like"):]
    block = re.search(r"```text\n\$ (.*?)\n(.*?)```", section, re.S)
    assert block is not None, "the README shows no failing run"
    return block.group(1), block.group(2)


@pytest.mark.slow
def test_the_readme_failing_run_fails_as_shown() -> None:
    command, shown = _readme_failing_run()
    words = shlex.split(command)
    assert words[0] == "mcp-conform"
    spawn = words.index("--spawn") + 1
    words[spawn] = re.sub(r"^python ", shlex.quote(sys.executable) + " ", words[spawn])
    env = dict(os.environ, PYTHONPATH=str(ROOT), NO_COLOR="1", COLUMNS="200")
    proc = subprocess.run([sys.executable, "-m", "mcp_conform.conformance", *words[1:]], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=240)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 1, out
    # the lines that do not depend on the run's random sequence numbers, as shown
    failed = [ln for ln in shown.splitlines() if ln.startswith(("FAILED ", "root failures"))]
    failed.append(next(ln for ln in shown.splitlines() if "(MUST): " in ln).strip())
    def plain(text: str) -> str:  # spaces folded, a case's duration dropped (it differs run to run)
        return re.sub(r" \d+\.\d+ s\b", " s", re.sub(r"[ \t]+", " ", text))

    for line in failed:
        assert plain(line).strip() in plain(out), (line, out)
    summary = next(ln for ln in shown.splitlines() if ln.endswith(" error"))
    assert summary in out, (summary, out)


@pytest.mark.slow  # a whole site build: MkDocs, and a fresh interpreter for each command's --help
def test_docs_site_builds_strict(tmp_path: Path) -> None:
    pytest.importorskip("mkdocs", reason="MkDocs is not installed: pip install -e '.[docs]'")
    pytest.importorskip("material", reason="MkDocs Material is not installed: pip install -e '.[docs]'")
    env = dict(os.environ, PYTHONPATH=str(ROOT), NO_MKDOCS_2_WARNING="1")
    # not --quiet: it hides the warnings from the count that --strict fails on (MkDocs 1.6)
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict",
                           "--config-file", str(ROOT / "mkdocs.yml"), "--site-dir", str(tmp_path / "site")],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    cli = (tmp_path / "site" / "reference" / "cli" / "index.html").read_text(encoding="utf-8")
    for command in SCRIPTS:  # the generated reference holds every command's --help
        assert f"usage: {command}" in cli, command
    rules = (tmp_path / "site" / "spec" / "index.html").read_text(encoding="utf-8")
    assert "MCP-ACK-2" in rules


def test_sources_cite_the_design_page_users_have() -> None:
    """Source files and schemas cite docs/design.md (shipped with the docs), not a DESIGN.md
    users never see; every section a citation names in quotes is a heading of that page."""
    tracked = subprocess.run(["git", "ls-files", "*.py", "*.json", "*.yaml", "*.lua", "*.c"], cwd=ROOT,
                             capture_output=True, text=True)
    if tracked.returncode != 0:
        pytest.skip("not a git checkout: the tracked files cannot be listed")
    design = (ROOT / "docs" / "design.md").read_text(encoding="utf-8")
    headings = {h.strip() for h in re.findall(r"^#+ (.+)$", design, re.M)}
    cited = 0
    for name in tracked.stdout.split():
        if name.startswith("tests/"):
            continue
        text = (ROOT / name).read_text(encoding="utf-8", errors="replace")
        assert "DESIGN.md" not in text, f"{name} cites DESIGN.md"
        for double, single in re.findall(r"docs/design\.md,?\s+\(?(?:\"([^\"]+)\"|'([^']+)')", text):
            section = double or single
            cited += 1
            assert " ".join(section.split()) in headings, (name, section, sorted(headings))
    assert cited >= 10, cited
