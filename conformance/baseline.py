"""Expected-failures baselines: ``--baseline FILE`` and ``--write-baseline FILE``.

A node that is known to break a rule should not turn every CI run red while it is being
fixed, and the day it is fixed CI should say so. A baseline lists, by case ID or rule ID,
what is expected to fail, each with the reason it is accepted::

    # mcp-conform expected-failures baseline
    version: 1
    expected_failures:
      - id: ACK/test_ack_payload_is_the_big_endian_seq   # a case ID ...
        reason: "firmware 2.3 sends the seq little-endian; fixed in 2.4"
      - id: MCP-RTX-3                                     # ... or a rule ID
        reason: "retransmission jitter on the bench radio"

JSON with the same shape is read too (the file's suffix does not matter). With a baseline,
a listed case that fails or warns is reported ``xfailed`` (not a failure: exit 0), and a
listed case that now passes is ``xpassed`` (reported; exit 1 under ``--strict``, so a fixed
bug must be taken off the list). A rule ID entry lists every case whose failure names that
rule, and every case verifying only that rule for ``xpassed``. A case that errors or skips
is left as it is: a baseline excuses what the node did, never a run that could not judge it.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcp_conform.spec import SPEC

__all__ = ["Baseline", "BaselineError", "BaselineEntry", "load_baseline", "write_baseline"]

BASELINE_VERSION = 1
_RULE_ID = re.compile(r"^MCP-[A-Z]+-[0-9]+$")


class BaselineError(ValueError):
    """A baseline file that cannot be used; the message names the file and the problem."""


@dataclass(frozen=True)
class BaselineEntry:
    """One expected failure: a case ID or a rule ID, and why it is accepted."""

    id: str
    reason: str

    @property
    def is_rule(self) -> bool:
        return bool(_RULE_ID.match(self.id))


@dataclass(frozen=True)
class Baseline:
    """The expected failures of one node, looked up by case."""

    path: str
    entries: tuple[BaselineEntry, ...]

    def match(self, case_id: str, rules: Iterable[str], failed_rule: str | None) -> BaselineEntry | None:
        """The entry that lists this case: its case ID, the rule its failure names, or (for
        a case that did not fail) the one rule it verifies."""
        rules = tuple(rules)
        for e in self.entries:
            if e.is_rule:
                if failed_rule is not None and e.id == failed_rule:
                    return e
                if failed_rule is None and rules and all(r == e.id for r in rules):
                    return e
            elif e.id == case_id:
                return e
        return None


def _entries(doc: Any, where: str) -> tuple[BaselineEntry, ...]:
    if isinstance(doc, dict):
        version = doc.get("version", BASELINE_VERSION)
        if version != BASELINE_VERSION:
            raise BaselineError(f"{where}: version {version!r} is not supported (expected {BASELINE_VERSION})")
        items = doc.get("expected_failures", [])
    elif isinstance(doc, list):
        items = doc
    elif doc is None:
        items = []
    else:
        raise BaselineError(f"{where}: expected a mapping with 'expected_failures', got {type(doc).__name__}")
    if not isinstance(items, list):
        raise BaselineError(f"{where}: 'expected_failures' must be a list")
    out: list[BaselineEntry] = []
    seen: set[str] = set()
    for n, item in enumerate(items, 1):
        if isinstance(item, str):
            item = {"id": item}
        if not isinstance(item, dict) or not isinstance(item.get("id"), str) or not item["id"].strip():
            raise BaselineError(f"{where}: entry {n} needs an 'id' (a case ID or a rule ID)")
        ident = item["id"].strip()
        if _RULE_ID.match(ident) and ident not in SPEC.rules_by_id:
            raise BaselineError(f"{where}: entry {n}: {ident} is not a rule of the spec")
        reason = item.get("reason")
        if not isinstance(reason, str) or not reason.strip():
            raise BaselineError(f"{where}: entry {n} ({ident}) needs a 'reason'")
        if ident in seen:
            raise BaselineError(f"{where}: {ident} is listed twice")
        seen.add(ident)
        out.append(BaselineEntry(ident, reason.strip()))
    return tuple(out)


def load_baseline(path: str | Path, option: str = "--baseline") -> Baseline:
    """Read a YAML or JSON baseline; ``BaselineError`` (one line) when it cannot be used."""
    where = f"{option}: {str(path)!r}"
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise BaselineError(f"{where}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise BaselineError(f"{where}: cannot read it ({getattr(exc, 'strerror', None) or exc})") from None
    import yaml  # here, not at the top: every run imports this module, few read a baseline

    try:
        doc = json.loads(text) if text.lstrip().startswith(("{", "[")) else yaml.safe_load(text)
    except RecursionError:
        raise BaselineError(f"{where}: nested deeper than a baseline is") from None
    except (json.JSONDecodeError, yaml.YAMLError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise BaselineError(f"{where}: not YAML or JSON ({first})") from None
    return Baseline(str(path), _entries(doc, where))


def baseline_entries_from(cases: Iterable[Any]) -> list[BaselineEntry]:
    """What a run found, as baseline entries: each failed or warned case, with the rule
    its failure names and what was seen as the reason."""
    out = []
    for c in cases:
        if c.outcome not in ("failed", "warned", "xfailed"):
            continue
        what = c.failed_rule or " ".join(c.rules)
        seen = f": {c.actual}" if c.actual else ""
        out.append(BaselineEntry(c.id, f"{what}{seen}"[:300]))
    return out


def write_baseline(path: str | Path, cases: Iterable[Any], target: str | None = None) -> int:
    """Write a baseline of a run's failures (YAML unless the name ends in .json); returns
    how many entries it holds. ``OSError`` names the file."""
    entries = baseline_entries_from(cases)
    items = [{"id": e.id, "reason": e.reason} for e in entries]
    try:
        if str(path).endswith(".json"):
            text = json.dumps({"version": BASELINE_VERSION, "expected_failures": items}, indent=2) + "\n"
        else:
            import yaml

            head = (f"# mcp-conform expected-failures baseline{f' for {target}' if target else ''}\n"
                    "# Each entry: a case ID or rule ID and why its failure is accepted for now.\n")
            text = head + yaml.safe_dump({"version": BASELINE_VERSION, "expected_failures": items},
                                         sort_keys=False, allow_unicode=True, width=100)
        Path(path).write_text(text, encoding="utf-8")
    except OSError as exc:
        raise OSError(f"--write-baseline: cannot write {str(path)!r}: {exc.strerror}") from None
    return len(entries)
