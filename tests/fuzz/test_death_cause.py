"""A backend's death is named by what killed it (issue 36: a real Nsqd backend built with ASan's
halt_on_error=0 over-reads on every frame, and every death was named by that first report: its
aborting number parse, negative string length and GPX parser SEGV merged into one finding), and
a stack frame by its function, however C++ spells it."""

from __future__ import annotations

import sys
import textwrap
import time

from mcp_conform.fuzz.nsqd_oracles import frame_name, parse_cause
from mcp_conform.harness.procs import ManagedProcess

OVERREAD = """\
==7==ERROR: AddressSanitizer: heap-buffer-overflow on address 0x602 at pc 0x55 bp 0x7f sp 0x7f
READ of size 1 at 0x602 thread T0
    #0 0x55 in Decoder::readByte() /src/Message.hpp:40:12
    #1 0x55 in Server::HandleConnection() /src/Server.cpp:120:5
"""


def _stderr_of(script: str) -> ManagedProcess:
    proc = ManagedProcess([sys.executable, "-c", textwrap.dedent(script)])
    proc.proc.wait(timeout=20)
    deadline = time.monotonic() + 5
    while proc.alive() and time.monotonic() < deadline:
        time.sleep(0.01)
    return proc


def test_the_latest_cause_names_the_death_not_the_first_report():
    proc = _stderr_of(f"""
        import sys
        sys.stderr.write({OVERREAD!r} * 3)
        sys.stderr.write("terminate called after throwing an instance of 'std::length_error'\\n")
        sys.stderr.write("  what():  basic_string::_M_create\\n")
        sys.stderr.flush()
        """)
    assert "heap-buffer-overflow" in proc.sanitizer_report()[0]  # the first report is kept as before
    assert parse_cause(proc.last_cause()) == ("abort: uncaught std::length_error", "", ())


def test_a_later_sanitizer_report_is_the_cause():
    segv = ("==7==ERROR: AddressSanitizer: SEGV on unknown address 0x000000000000\\n"
            "    #0 0x55 in tinyxml2::XMLNode::FirstChildElement(char const*) const /src/tinyxml2.cpp:9\\n"
            "    #1 0x55 in Server::HandleUploadFlightpath(Decoder&) /src/Server.cpp:300\\n")
    proc = _stderr_of(f"""
        import sys
        sys.stderr.write({OVERREAD!r})
        sys.stderr.write("{segv}")
        sys.stderr.flush()
        """)
    kind, _, frames = parse_cause(proc.last_cause())
    assert kind == "SEGV" and frames[:2] == ("tinyxml2::XMLNode::FirstChildElement",
                                             "Server::HandleUploadFlightpath"), frames


def test_frame_names_drop_return_type_templates_parameters_and_location():
    assert frame_name("char* std::__find_if<char*, __gnu_cxx::__ops::_Iter_pred<bool (*)(char)> >"
                      "(char*, char*) /usr/include/c++/12/bits/stl_algobase.h:2100") == "std::__find_if"
    assert frame_name("handle_frame /src/b.c:40:3") == "handle_frame"  # C: as before
    assert frame_name("main (/tmp/x+0x1234)") == "main"
    # a frame without a parameter list: its first word (its location follows), as before
    assert frame_name("__strlen_evex ../sysdeps/x86_64/multiarch/strlen-evex.S:79") == "__strlen_evex"


def test_the_c_librarys_frames_are_not_the_targets():
    report = ["==7==ERROR: AddressSanitizer: SEGV on unknown address 0x000000000000",
              "    #0 0x7f in __strlen_evex ../sysdeps/x86_64/multiarch/strlen-evex.S:79",
              "    #1 0x55 in __interceptor_strlen ../../../../src/libsanitizer/sanitizer_common/x.inc:387",
              "    #2 0x55 in Server::HandleConnection() /src/Server.cpp:150"]
    assert parse_cause(report) == ("SEGV", "", ("Server::HandleConnection",))
