"""A sanitizer's whole report, then the process's exit (ASan's default, halt_on_error): on a
loaded host the exit came more than 0.3 s after the report's SUMMARY, and the crash was
classed as a report of a process still running, so its replay said "did not reproduce"
(CI: test_nsqd_repro, the oracle "sanitizer" where the finding's is "crash")."""

from __future__ import annotations

import time
from types import SimpleNamespace

from mcp_conform.fuzz.nsqd_backend import Backend, Traits
from mcp_conform.harness.nsqd_session import Death

REPORT = [
    "==1==ERROR: AddressSanitizer: heap-buffer-overflow on address 0x6020 at pc 0x55 bp 0x7f sp 0x7f",
    "READ of size 65535 at 0x6020 thread T0",
    "    #0 0x55 in check_string /src/backend.c:120",
    "    #1 0x55 in check_body /src/backend.c:200",
    "SUMMARY: AddressSanitizer: heap-buffer-overflow /src/backend.c:120 in check_string",
]


def _backend(exits_after: float, line_at: tuple[float, ...] = (0.0,) * len(REPORT)) -> Backend:
    """A process whose report's lines show at ``line_at`` (seconds after the first), which
    exits ``exits_after`` seconds after it started."""
    born = time.monotonic()

    def report() -> list[str]:
        age = time.monotonic() - born
        return [line for line, at in zip(REPORT, line_at, strict=True) if at <= age]

    proc = SimpleNamespace(sanitizer_report=report, last_cause=report, alive=lambda: time.monotonic() - born < exits_after,
                           cause_time=lambda: born, report_time=lambda: born)

    def death(grace: float = 0.0):
        end = time.monotonic() + grace
        while proc.alive() and time.monotonic() < end:
            time.sleep(0.005)
        return None if proc.alive() else Death(-6, "SIGABRT", REPORT[0], tuple(REPORT))

    b = object.__new__(Backend)
    b.session = SimpleNamespace(node=SimpleNamespace(process=proc), death=death)
    b.reports_seen = 0
    b.traits = Traits()
    return b


def test_a_process_that_exits_a_second_after_its_whole_report_is_a_crash():
    hit = _backend(exits_after=1.0).report_hit()
    assert hit is not None and hit.signature.oracle == "crash", hit
    assert hit.signature.frames[:2] == ("check_string", "check_body"), hit.signature


def test_a_report_whose_stacks_take_half_a_second_to_symbolise_is_waited_for():
    """CI, loaded: the report's lines came with a gap longer than the old 0.3-s quiet spell
    (the stacks symbolised one by one), the wait ended without the SUMMARY and the crash that
    followed was classed as a report of a process still running."""
    hit = _backend(exits_after=1.4, line_at=(0.0, 0.0, 0.5, 0.5, 1.0)).report_hit()
    assert hit is not None and hit.signature.oracle == "crash", hit


def test_a_replay_waits_for_a_crash_whose_report_begins_late():
    """A replay has no next case to show a death: it waited 0.5 s, then classed whatever part
    of a report it found as "sanitizer" (CI, loaded: the finding, a crash, "did not
    reproduce"). Now it waits for the death or the report's start, and takes the report whole."""
    from mcp_conform.fuzz.nsqd_backend import _replay

    sig = _backend(exits_after=0.0).report_hit().signature
    assert sig.oracle == "crash"
    ok, _, hit = _replay(_backend(exits_after=1.6, line_at=(0.7, 0.7, 1.0, 1.0, 1.3)), [], sig, probe=False)
    assert ok and hit.signature.oracle == "crash", hit
    ok, _, hit = _replay(_backend(exits_after=99.0, line_at=(99.0,) * len(REPORT)), [], sig, probe=False)
    assert not ok and hit is None  # nothing comes: not reproduced, after the bounded wait
