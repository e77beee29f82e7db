"""spec.docs: docs/spec.md is generated from the spec, complete, and current."""

from __future__ import annotations

from pathlib import Path

from mcp_conform.spec import SPEC
from mcp_conform.spec.docs import check, render, write

PAGE = Path(__file__).resolve().parents[2] / "docs" / "spec.md"


def test_committed_page_is_current() -> None:
    assert PAGE.is_file(), "docs/spec.md is missing: run `python -m mcp_conform.spec docs`"
    assert PAGE.read_text(encoding="utf-8") == render(SPEC), (
        "docs/spec.md is stale: run `python -m mcp_conform.spec docs` and commit it")


def test_page_shows_every_rule_note_action_and_parameter() -> None:
    page = render(SPEC)
    for rule in SPEC.rules:
        row = next(line for line in page.splitlines() if line.startswith(f"| {rule.id} "))
        assert f"| {rule.level} |" in row and rule.text[:40] in row
        for dep in rule.depends_on:
            assert dep in row
    for note in SPEC.errata + SPEC.decisions:
        assert f"**{note.id} {note.title}**" in page
    for action in SPEC.actions:
        assert f"`{action.wire_name}`" in page
    for name in SPEC.params:
        assert f"`{name}`" in page
    for heading in ("## Header", "## Action codes", "## Payload layouts", "## Mission item",
                    "## Parameters", "## Errata and decisions", "## Rules"):
        assert heading in page
    assert "4E 43 53 55 2D 43 4D 01 01" in page
    assert "observe (drone)" in page and "observe (manager)" in page


def test_write_and_check(tmp_path: Path) -> None:
    out = tmp_path / "d" / "spec.md"
    assert not check(SPEC, out)
    write(SPEC, out)
    assert check(SPEC, out)
    out.write_text(out.read_text() + "edit\n")
    assert not check(SPEC, out)
