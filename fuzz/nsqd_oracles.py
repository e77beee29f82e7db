"""What the Nsqd fuzzer judges a backend by, and how a finding is named.

Oracles (issue 21): the process's death in spawn mode (signal or exit code); an
AddressSanitizer or UBSan report on its stderr, parsed into kind, access and the target's
top frames, also when the process goes on (``halt_on_error=0``); a hang (no new connection
accepted, or no UPDATE on it, within a bound); a close of a connection on which only frames
the spec says a backend handles were sent; a frame from the backend that breaks NSQD-FRM-1
or NSQD-MSG-2 (``harness.nsqd_session.Conn.violation``, the runner's own judgement); the
stream losing sync or a command losing its effect (a probe command after the case does not
take its effect); descriptors that grow with connection cycles. A finding's
:class:`Signature` deduplicates: (oracle, signal or sanitizer kind, top frames) or
(oracle, rule).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

__all__ = ["CLOSE_RULE", "Hit", "Signature", "desync_rule", "parse_sanitizer", "same_finding"]

_ASAN = re.compile(r"ERROR: (\w+Sanitizer): ([\w-]+)")
_UBSAN = re.compile(r"runtime error: (.*)")
_ACCESS = re.compile(r"^(READ|WRITE) of size (\d+)")
_FRAME = re.compile(r"#\d+ 0x[0-9a-f]+ in (.+)$")
_TEMPLATE = re.compile(r"<[^<>]*>")
_TERMINATE = re.compile(r"terminate called after throwing an instance of '([^']+)'")
_SKIP = ("__interceptor_", "__asan", "__ubsan", "__sanitizer", "_start", "__libc_start", "abort", "raise",
         "__GI_", "__pthread_kill", "std::", "__cxa", "__gnu_cxx")


@dataclass(frozen=True)
class Signature:
    """What a finding is, for deduplication and for its name."""

    oracle: str  # crash | sanitizer | hang | close | protocol | desync | leak
    kind: str  # SIGSEGV, heap-buffer-overflow, NSQD-FRM-1, ...
    frames: tuple[str, ...] = ()
    rule: str = "NSQD-ROB-1"
    access: str = ""

    @property
    def key(self) -> tuple[str, str, tuple[str, ...]]:
        return (self.oracle, self.kind, self.frames[:3])

    def describe(self) -> str:
        where = f" in {' < '.join(self.frames[:3])}" if self.frames else ""
        access = f" ({self.access})" if self.access else ""
        return f"{self.oracle}: {self.kind}{access}{where} [{self.rule}]"


@dataclass(eq=False)
class Hit(Exception):
    """What an oracle saw: returned by a case's judgement (``fuzz.nsqd_backend``), raised
    inside a stateful program's player (``fuzz.nsqd_player``); the one kind for both."""

    signature: Signature
    detail: str
    stderr: tuple[str, ...] = ()
    suspects: int = 2  # how many of the latest cases may have caused it (the campaign's triage)
    #: when its cause showed (time.monotonic(): a sanitizer's report or a "terminate called"
    #: line read from stderr), None if unknown: the cases sent before it are the suspects
    at: float | None = None

    def __str__(self) -> str:
        return self.signature.describe()

    def __reduce__(self) -> tuple[type[Hit], tuple[Signature, str, tuple[str, ...], int, float | None]]:
        return (Hit, (self.signature, self.detail, self.stderr, self.suspects, self.at))


def frame_name(text: str) -> str:
    """The function a sanitizer stack frame names, from what follows its ``in``: its return
    type, template arguments, parameters and source location dropped
    (``char* std::__find_if<char*, ...>(char*, ...) /usr/include/...`` -> ``std::__find_if``,
    ``tinyxml2::XMLNode::FirstChildElement(char const*) const /src/x.cpp:12`` ->
    ``tinyxml2::XMLNode::FirstChildElement``, ``handle_frame /src/b.c:40`` -> ``handle_frame``)."""
    for _ in range(16):  # nested templates, innermost first; bounded
        stripped = _TEMPLATE.sub("", text)
        if stripped == text:
            break
        text = stripped
    words = text.split("(", 1)[0].split()
    if not words:
        return ""
    # with a parameter list, the name is the last word before it (a return type may precede);
    # without one (C, or no symbols' types), the first word (its source location follows)
    return words[-1] if "(" in text and not text.split("(", 1)[0].rstrip().endswith(" ") else words[0]


def parse_cause(lines: list[str]) -> tuple[str, str, tuple[str, ...]] | None:
    """(kind, access, frames) of a cause of death (``ManagedProcess.last_cause``): a sanitizer
    report, or an uncaught C++ exception (``abort: uncaught std::length_error``), else None."""
    m = _TERMINATE.search(lines[0]) if lines else None
    if m:
        return f"abort: uncaught {m.group(1)}", "", ()
    return parse_sanitizer(lines)


def parse_sanitizer(lines: list[str]) -> tuple[str, str, tuple[str, ...]] | None:
    """(kind, access, the target's top frames) of the first sanitizer report in ``lines``."""
    kind = access = ""
    start = None
    for i, line in enumerate(lines):
        m = _ASAN.search(line)
        if m:
            kind, start = m.group(2), i
            break
        m = _UBSAN.search(line)
        if m:
            kind, start = "ubsan: " + re.sub(r"-?\d+", "N", m.group(1))[:60], i
            loc = line.split(": runtime error")[0].strip()
            return kind, "", (loc.rsplit("/", 1)[-1],) if loc else ()
    if start is None:
        return None
    frames: list[str] = []
    for line in lines[start + 1:start + 60]:
        a = _ACCESS.search(line.strip())
        if a and not access:
            access = f"{a.group(1)} of size {a.group(2)}"
        f = _FRAME.search(line)
        name = frame_name(f.group(1)) if f else ""
        if name and not name.startswith(_SKIP) and not name.startswith("__"):  # "__": the C library's
            frames.append(name)
            if len(frames) == 5:
                break
        if line.strip() == "" and frames:
            break
    return kind, access, tuple(frames)


#: a close after frames a backend handles, by the case's kind: the rule it breaks
CLOSE_RULE = {"split-writes": "NSQD-FRM-2", "batched": "NSQD-FRM-3", "valid": "NSQD-FRM-5",
               "body-padded": "NSQD-FRM-5", "gpx-size": "NSQD-FRM-5"}


def desync_rule(kind: str) -> str:
    """The rule a stream that lost its sync after a case of ``kind`` breaks (both engines)."""
    return ("NSQD-MSG-4" if kind == "bad-id" else "NSQD-ROB-3" if kind.endswith("mid-frame")
            else "NSQD-FRM-2" if kind == "split-writes" else "NSQD-FRM-3" if kind == "batched"
            else "NSQD-MSG-7")


def same_finding(seen: Signature, want: Signature) -> bool:
    """The same finding: equal keys; a lost stream is one whatever the probe that showed it."""
    if seen.oracle == want.oracle == "desync":
        return True
    if {seen.oracle, want.oracle} <= {"crash", "sanitizer"}:  # a report seen before or after the exit
        return (seen.kind, seen.frames[:3]) == (want.kind, want.frames[:3])
    return seen.key == want.key
