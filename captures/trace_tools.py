"""``mcp-capture check|show|diff|export|replay`` of a protocol whose captures a monitor judges
record by record, declared once, the protocol a parameter (docs/design.md "A protocol is a
plug-in"). A protocol's capture tools module (its profile's ``capture_tools``:
``captures.mavlink``, ``captures.nsqd``) declares a :class:`CapturePlugin` -- its name and
spec, what its captures are called, how it reads and judges one (its reader, framing and
monitor: :meth:`CapturePlugin.check`) and compares two (:meth:`CapturePlugin.compare`) --
and takes each subcommand's frame from here:

- ``check`` (:func:`run_check`): the verdict (the monitors' one verdict interface,
  ``judge.verdicts``: FAILED, else INCOMPLETE for a capture cut short, else OK), the JSON
  report (``--json``: the one document of every protocol, ``captures.check_doc``), the terminal
  report (the plug-in's lines, then each rule broken with its level,
  text, examples and how many more, the rules line, the verdict) and the exit code (0 none
  broken, 1 broken);
- ``show`` (:func:`show_frames`, every protocol's but MCP's: of a capture read through its
  monitor, :class:`Judged`, :func:`judge_records`, or of a stream capture's records as they are
  read, ``captures.stream_tools``): the time window (:func:`window`), the case window
  (:func:`case_window`, :func:`case_at`: a run's case marks), each frame a line with its time
  (and the rules its violations name it in), the truncation;
- ``diff`` (:func:`run_diff`): the notes, each capture's truncation, the JSON report, same
  (exit 0) or each divergence (exit 1); two captures' steps compared sender by sender
  (:func:`align`);
- ``--select``/``--exclude`` of a protocol's rules (:func:`selection`, as the monitors' one
  verdict interface takes them: ``judge.verdicts``);
- the one-line notes and refusals of what a protocol does not do (:func:`note`,
  :func:`not_exported`, :func:`not_replayed`).

The plug-in is what ``captures.cli.capture_tools`` hands each subcommand (its module's
``PLUGIN``): every protocol's ``check``, ``show``, ``diff``, ``export`` and ``replay`` go the one
path, the protocol a parameter; MCP's plug-in (``captures.mcp``) gives each its own module's.

The text a protocol's records are shown in is its own.
"""

from __future__ import annotations

import difflib
import json
import sys
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from mcp_conform.judge.verdicts import Found, Verdicts
from mcp_conform.traceio.grammar import write_text
from mcp_conform.traceio.reader import CaptureError, CaseMark, Truncated

__all__ = ["EXAMPLES", "CapturePlugin", "Checked", "Compared", "Judged", "RuleBlock", "align", "case_at", "case_window", "checked",
           "found_line", "judge_records", "not_exported", "not_replayed", "note", "run_check", "run_diff", "selection", "show_frames", "strict",
           "window"]


EXAMPLES = 3  # violations shown in full per rule in the terminal (all of them with -v and in --json)


@dataclass
class RuleBlock:
    """A broken rule in the terminal report: its examples (a line, its evidence lines) and
    how many more there are (``unit``: what they are, after the count)."""

    rule: str
    examples: list[tuple[str, Sequence[str]]]
    more: int = 0
    unit: str = ""


@dataclass
class Checked:
    """A capture judged: the report's lines before the rules (``head``) and after the rules
    line (``tail``), the broken rules' blocks, the monitor's verdicts (``judge.verdicts``) and
    the document (``captures.check_doc``)."""

    head: list[str]
    blocks: list[RuleBlock]
    verdicts: Verdicts
    doc: dict[str, Any]
    tail: list[str] = field(default_factory=list)


@dataclass
class Compared:
    """Two captures compared: each divergence (for ``--json``) and the terminal's lines of
    them, what ``same:`` and ``different: N divergence(s)`` go on to say, the notes, each
    side's (path, truncation), and the JSON document beside ``same`` and the divergences."""

    divergences: list[Any]
    lines: list[str]
    same: str
    over: str
    sides: list[tuple[str, str | None]]
    notes: list[str] = field(default_factory=list)
    doc: dict[str, Any] = field(default_factory=dict)


class CapturePlugin:
    """A protocol's captures as ``mcp-capture`` reads them (see the module docstring): its
    content (:meth:`check`, :meth:`compare`, :meth:`judged` and :meth:`frame_line` for
    ``show``) and each subcommand's work (``captures.cli.CaptureTools``), the core's with the
    protocol a parameter unless the protocol has its own."""

    name: str  # its --protocol
    spec: Any  # its spec: each rule's level and text (``spec.rule(ID)``)
    a_capture: str  # what one capture is called, with its article (check --html is not written for it)
    html_instead: str  # what check --html is told to use instead
    json_when_same = True  # diff --json is written when the captures are alike too
    EXPORTED = "records"  # what ``export`` writes, as its closing line counts them
    unexported = "is not exported as pcap"  # why export refuses one of its captures
    unreplayed = "is not replayed"  # why replay refuses one
    unchartered = "is not drawn"  # what show says of --svg

    def check(self, ns: Any) -> Checked:
        raise NotImplementedError

    #: what diff's steps are (its words: "same: N STEPS alike, each sender's in order ...")
    steps_called, steps_aside = "step(s)", ""

    def compare(self, golden: str, candidate: str) -> Compared:
        """Two captures read through their monitors, their :meth:`steps` compared sender by
        sender (:func:`align`)."""
        g, c = self.judged(golden, keep=True), self.judged(candidate, keep=True)
        ga, ca = self.steps(g), self.steps(c)
        diffs, lines = align(ga, ca)
        n_g, n_c = sum(map(len, ga.values())), sum(map(len, ca.values()))
        return Compared(diffs, lines, f"{n_g} {self.steps_called} alike, each sender's in order{self.steps_aside}",
                        f" over {n_g} and {n_c} {self.steps_called}", [(g.path, g.truncated), (c.path, c.truncated)],
                        doc={"golden_steps": n_g, "candidate_steps": n_c})

    def steps(self, j: Judged) -> dict[str, list[tuple[str, str]]]:
        """What diff compares of a judged capture: each sender's steps in order, (key compared,
        line shown)."""
        raise NotImplementedError

    def judged(self, path: str, *, keep: bool = False) -> Judged:
        """A capture read through its monitor (``keep``: its frames kept, for show)."""
        raise NotImplementedError

    def header(self, j: Judged) -> str:
        """``show``'s first line."""
        raise NotImplementedError

    def frame_line(self, f: Any, j: Judged) -> str:
        """``show``'s line of one frame, after its time (:func:`show_frames`) and before its marks."""
        raise NotImplementedError

    # -- the subcommands (captures.cli.CaptureTools) ------------------------------------
    def run_check(self, ns: Any, out: TextIO | None = None) -> int:
        return run_check(self, ns, out)

    def run_show(self, ns: Any, out: TextIO | None = None) -> int:
        """``show`` of a capture read through its monitor: :func:`show_frames` of its kept
        frames, each marked with the rules whose violations name it (``✗ RULE, ...``)."""
        note("show", ns, "svg", self.unchartered)
        j = self.judged(ns.file, keep=True)
        marks: dict[int, list[str]] = {}
        for v in j.monitor.violations:
            for i in v.frames:
                marks.setdefault(i, []).append(v.rule)

        def line(f: Any) -> str:
            return self.frame_line(f, j) + (f"  ✗ {', '.join(marks[f.index])}" if f.index in marks else "")
        tail = [Truncated(j.truncated)] if j.truncated else []
        return show_frames(ns, out or sys.stdout, self.header(j), [*j.frames, *tail], line, path=j.path, cases=j.cases)

    def run_diff(self, ns: Any, out: TextIO | None = None, err: TextIO | None = None) -> int:
        return run_diff(self, ns, out)

    def export_pcap(self, capture: str | Path, out: str | Path) -> tuple[int, str | None]:
        raise not_exported(capture, self.unexported)

    def run_replay(self, ns: Any, out: TextIO | None = None, err: TextIO | None = None) -> int:
        return not_replayed(err, ns.capture, self.unreplayed)


def checked(plugin: CapturePlugin, ns: Any, v: Verdicts, first: list[str], file: dict[str, Any],
            parameters: dict[str, Any], nodes: list[Any], *, first_ns: int | None, after: Sequence[str] = (),
            own: dict[str, Any] | None = None, line: Callable[[Found], str] = str, unit: str = "",
            more: Callable[[Found], dict[str, Any]] = lambda f: {}, tail: Sequence[str] = ()) -> Checked:
    """A capture judged by a monitor that gives one verdict per rule (``judge.verdicts``): the
    terminal's head (``first``, the truncation, the file's notes, ``after``), each broken rule's
    examples (``line`` each; all of them with ``-v``, else :data:`EXAMPLES`; ``unit``: what the
    rest are) and the document (``captures.check_doc``: ``file``, ``parameters`` beside
    ``--select`` and ``--strict``, ``nodes``, each violation with ``more`` of it, ``own``)."""
    from mcp_conform.captures.check_doc import document, violation_json

    head = [*first, *([f"TRUNCATED: {v.truncated} (judged up to there)"] if v.truncated else []),
            *(f"note: {n}" for n in file["notes"]), *after]
    examples = 10**9 if getattr(ns, "verbose", False) else EXAMPLES
    blocks = []
    for rule in (r for r, verdict in v.rules.items() if verdict in ("failed", "warned")):
        found = [f for f in v.found if f.rule == rule]
        blocks.append(RuleBlock(rule, [(line(f), f.evidence) for f in found[:examples]],
                                v.counts[rule] - min(len(found), examples), unit))
    doc = document(v, plugin.spec, file, {"select": list(selection(ns)), "strict": strict(ns), **parameters}, nodes,
                   [{**violation_json(f, plugin.spec, first_ns), **more(f)} for f in v.found], own)
    return Checked(head, blocks, v, doc, list(tail))


def found_line(who: str, f: Found, first_ns: int, case: str | None = None) -> str:
    """A violation's line in the terminal report: ``who`` broke it (a node, a connection), when
    (seconds since the capture's first record, ``first_ns``), in which ``case`` of a run's
    capture, what was expected and what was seen."""
    return (f"{who} at +{(f.t_ns - first_ns) / 1e9:.6f}s{f' in {case}' if case else ''}: expected {f.expected}; "
            f"actual {f.actual}")


def strict(ns: Any) -> bool:
    """``--strict``: a SHOULD broken counts against the exit code too."""
    return bool(getattr(ns, "strict", False))


def note(command: str, ns: Any, option: str, text: str) -> None:
    """One line on stderr where ``--OPTION`` was given to what does not take it."""
    if getattr(ns, option, None):
        sys.stderr.write(f"mcp-capture {command}: note: --{option} {text}\n")


def run_check(plugin: CapturePlugin, ns: Any, out: TextIO | None = None) -> int:
    """``mcp-capture check`` of a capture of ``plugin``'s (see the module docstring)."""
    from mcp_conform.captures.cli import to_terminal

    note("check", ns, "html", f"is not written for {plugin.a_capture} ({plugin.html_instead})")
    c = plugin.check(ns)
    verdict = c.verdicts.verdict
    if getattr(ns, "json", None):  # the file first: a piped terminal report loses nothing of it
        write_text(ns.json, json.dumps(c.doc, indent=2) + "\n")

    def report() -> None:
        write = (out or sys.stdout).write
        for line in c.head:
            write(line + "\n")
        for b in c.blocks:
            r = plugin.spec.rule(b.rule)
            write(f"{b.rule} {r.level}: {r.text}\n")
            for line, evidence in b.examples:
                write(f"  {line}\n")
                for e in evidence:
                    write(f"    {e}\n")
            if b.more > 0:
                write(f"  ... and {b.more} more{b.unit}\n")
        write("rules: " + ", ".join(f"{r} {v}" for r, v in c.verdicts.rules.items()) + "\n")
        for line in c.tail:
            write(line + "\n")
        write(f"verdict: {verdict}\n")

    to_terminal(report)
    return c.verdicts.exit_code


def run_diff(plugin: CapturePlugin, args: Any, out: TextIO | None = None) -> int:
    """``mcp-capture diff`` of two captures of ``plugin``'s: exit 0 same, 1 different. The
    ``--json`` file first, then the terminal report as every command writes it
    (``captures.cli.to_terminal``: none with ``-q``, on stderr when the JSON goes to stdout)."""
    from mcp_conform.captures.cli import to_terminal

    c = plugin.compare(args.golden, args.candidate)
    same = not c.divergences
    if getattr(args, "json", None) and (plugin.json_when_same or not same):
        write_text(args.json, json.dumps({"protocol": plugin.name, "same": same, **c.doc,
                                          "divergences": c.divergences}, indent=1) + "\n")

    def report() -> None:
        o = out or sys.stdout  # looked up here: to_terminal may have put stderr in its place
        for line in c.notes:
            o.write(f"note: {line}\n")
        for path, truncated in c.sides:
            if truncated:
                o.write(f"note: {path} is TRUNCATED: {truncated}\n")
        if same:
            o.write(f"same: {c.same}\n")
            return
        o.write(f"different: {len(c.divergences)} divergence(s){c.over}\n")
        for line in c.lines:
            o.write(line + "\n")

    to_terminal(report)
    return 0 if same else 1


def window(ns: Any) -> Callable[[float], bool]:
    """``--from``/``--to`` (seconds since a capture's first record): whether a time is in."""
    lo = float(ns.t_from) if getattr(ns, "t_from", None) else None
    hi = float(ns.t_to) if getattr(ns, "t_to", None) else None
    return lambda rel: not ((lo is not None and rel < lo) or (hi is not None and rel > hi))


def case_window(cases: Sequence[CaseMark], case: str, path: str) -> tuple[int, int]:
    """``--case ID`` (or the one case ID starts): the span of its marks (to the end of a
    capture cut before its end mark); UsageError when the capture has no case marks, or ID
    names none or several."""
    from mcp_conform.captures.cli import UsageError

    ids = list(dict.fromkeys(m.case for m in cases))
    match = [c for c in ids if c == case] or [c for c in ids if c.startswith(case)]
    if len(match) != 1:
        what = "has no case marks" if not ids else ("matches several cases" if match else "is not a case of it")
        raise UsageError(f"--case: {case!r}: {path} {what}")
    marks = [m for m in cases if m.case == match[0]]
    start = min(m.t_ns for m in marks)
    # a case the capture was cut in (no end mark): to the capture's end, as MCP's show has it
    return start, max(m.t_ns for m in marks) if any(m.event == "end" for m in marks) else sys.maxsize


def case_at(cases: Sequence[CaseMark], t_ns: int) -> str | None:
    """The case whose marks hold ``t_ns`` (a run's capture), else None."""
    open_: dict[str, int] = {}
    found = None
    for m in cases:
        if m.event == "start":
            open_[m.case] = m.t_ns
        elif m.case in open_ and open_[m.case] <= t_ns <= m.t_ns:
            found = m.case
    return found


def not_exported(capture: str | Path, why: str) -> CaptureError:
    """``export`` of a capture whose protocol is not exported as pcap: one line, exit 2."""
    return CaptureError(f"{capture}: {why}")


def not_replayed(err: TextIO | None, capture: str | Path, why: str) -> int:
    """``replay`` of a capture whose protocol is not replayed: one line, exit 2."""
    (err or sys.stderr).write(f"mcp-capture: error: replay: {capture}: {why}\n")
    return 2


def selection(ns: Any) -> tuple[str, ...]:
    """``--select``/``--exclude`` as ``judge.verdicts.picked`` takes them (``!PREFIX``: left out)."""
    return tuple(getattr(ns, "select", None) or ()) + tuple("!" + x for x in getattr(ns, "exclude", None) or ())


@dataclass
class Judged:
    """A capture read through its monitor (fed each frame in order): what ``check``, ``show``
    and ``diff`` print. ``role``: the role under test the capture names, None: every role."""

    path: str
    format: str
    monitor: Any
    role: str | None
    frames: list[Any] = field(default_factory=list)  # kept for show and diff only
    cases: list[CaseMark] = field(default_factory=list)
    truncated: str | None = None
    count: int = 0

    @property
    def first_ns(self) -> int:
        return int(self.monitor.first_ns or 0)

    def case_at(self, t_ns: int) -> str | None:
        """The case whose marks hold ``t_ns`` (a run's capture), else None."""
        return case_at(self.cases, t_ns)


def judge_records(j: Judged, records: Iterable[Any], frame: type, *, keep: bool = False) -> Judged:
    """``records`` read into ``j``: each ``frame`` fed to its monitor (and kept: ``keep``),
    the case marks, the truncation."""
    for rec in records:
        if isinstance(rec, frame):
            j.monitor.feed(rec)
            j.count += 1
            if keep:
                j.frames.append(rec)
        elif isinstance(rec, CaseMark):
            j.cases.append(rec)
        elif isinstance(rec, Truncated):
            j.truncated = rec.reason
    return j


def show_frames(ns: Any, out: TextIO, header: str, records: Iterable[Any], line: Callable[[Any], str], *,
                path: str = "", cases: Sequence[CaseMark] | None = None, kinds: tuple[type, ...] = ()) -> int:
    """``show`` of a capture's records as they come (MAVLink's frames, kept and marked: ``CapturePlugin.
    run_show``; a stream protocol's writes, frames, events and gaps, read on: ``captures.stream_tools``):
    ``header``, then each record (of ``kinds``; all: none given) in ``--from``/``--to`` (seconds since
    the first such record) and ``--case`` (of ``cases``, a capture's case marks; None: not looked at) a
    line, its time and its ``line``; ``Truncated`` (the records' last) its line where it comes."""
    shown = window(ns)
    span = case_window(cases, ns.case, path) if cases is not None and getattr(ns, "case", None) else None
    out.write(header + "\n")
    first: int | None = None
    for rec in records:
        if type(rec) is Truncated:
            out.write(f"TRUNCATED: {rec.reason}\n")
            continue
        if kinds and type(rec) not in kinds:
            continue
        first = rec.t_ns if first is None else first
        if shown((rec.t_ns - first) / 1e9) and (span is None or span[0] <= rec.t_ns <= span[1]):
            out.write(f"+{(rec.t_ns - first) / 1e9:.6f}s {line(rec)}\n")
    return 0


def align(golden: dict[str, list[tuple[str, str]]], candidate: dict[str, list[tuple[str, str]]], *,
          shown: int = 20) -> tuple[list[dict[str, Any]], list[str]]:
    """Two captures' steps, sender by sender ((key compared, line shown), each sender's in its
    order), aligned by ``difflib``: the divergences (missing, extra, changed) and the
    terminal's lines of the first ``shown``."""
    diffs: list[dict[str, Any]] = []
    for role in sorted({*golden, *candidate}):
        a, b = golden.get(role, []), candidate.get(role, [])
        sm = difflib.SequenceMatcher(a=[k for k, _ in a], b=[k for k, _ in b], autojunk=False)
        for op, i1, i2, j1, j2 in sm.get_opcodes():
            if op != "equal":
                diffs.append({"kind": {"delete": "missing", "insert": "extra", "replace": "changed"}[op],
                              "role": role, "golden": [line for _, line in a[i1:i2]],
                              "candidate": [line for _, line in b[j1:j2]]})
    lines = []
    for d in diffs[:shown]:
        lines.append(f"  {d['kind']} ({d['role']}'s messages):")
        lines += [f"    golden    {line[:150]}" for line in d["golden"][:3]]
        lines += [f"    candidate {line[:150]}" for line in d["candidate"][:3]]
    if len(diffs) > shown:
        lines.append(f"  ... and {len(diffs) - shown} more")
    return diffs, lines
