"""``python bench/bench_fuzz.py --protocol nsqd``: mcp-fuzz beside boofuzz 0.4.2 against the
same Nsqd backend over TCP, in one run (issue 21 item 6).

For each backend (``--backend reference``: the embedded Python reference backend; ``c``: the
correct C backend of tests/nsqd_backends, built with ASan, at a 0.05 s UPDATE period and at
the spec's 0.4 s, D-8: a slow-updating backend, whose cases/s must come from overlapping
cases rather than waiting out each period, issue 36 item 5; ``both``), the same command is
started once for boofuzz and for ``mcp-fuzz attached``, and once more for ``mcp-fuzz
spawned`` (process oracles on: death, sanitizer reports, descriptors). Rows:

- ``boofuzz default``: a Session as boofuzz's documentation sets one up (web UI, text and
  database loggers, a new connection per test case, receiving after each request);
- ``boofuzz tuned``: no web UI, no loggers, ``fuzz_db_keep_only_n_pass_cases=1``, no receive,
  ``sleep_time=0``; still a new connection per test case (the backend closes the connection
  on a framing error, so a reused one would take the cases after it nowhere);
- ``mcp-fuzz <engine>``: its stateless engine, its stateful one (programs of two clients,
  pipelined and judged at their end, ``fuzz.nsqd_stateful``) and ``both`` (the default mix,
  the time split), every case judged (the backend's frames, effects, closes, probes for sync
  and liveness).

Each row also says what the reference backend parsed (frames, connections: its ``-v`` log)
and how many connection attempts the kernel dropped from a full listen queue meanwhile: a
blind sender outruns a one-client-at-a-time backend's accept loop, and each drop stalls it
for a SYN retransmission (1 s), so boofuzz's tuned figure varies widely from run to run. A
tuned session that reused its connection would count cases the backend never reads (after
the first framing error the connection is gone and boofuzz ignores the failed sends).

boofuzz's session is Nsqd's frames as the spec has them: one request per client message of
``spec/nsqd.yaml``, a 4-byte big-endian ``Size`` that counts itself (``inclusive``) over the
id byte and the body, each string field an int16 ``Size`` and its text (valid values as
defaults), int32/"float" fields as big-endian ``DWord``, bools as ``Byte``; boofuzz mutates
with its own primitives. Cases/s is test cases over the seconds the fuzz loop ran, for both
tools (mcp-fuzz: its judged cases/s, triage excluded; against a correct backend there is
none). Figures only; nothing asserts a timing.
"""

from __future__ import annotations

import contextlib
import os
import random
import shlex
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a source checkout

from bench.boofuzz_session import timed_session, web_port  # noqa: E402
from mcp_conform.fuzz.nsqd_campaign import StreamCampaign  # noqa: E402
from mcp_conform.fuzz.nsqd_mutators import valid_values  # noqa: E402
from mcp_conform.harness.nsqd_session import embedded_command  # noqa: E402
from mcp_conform.spec import NSQD  # noqa: E402

BOOFUZZ_MISSING = "boofuzz not installed (pip install -e '.[bench]'): its rows skipped"


def nsqd_requests(boofuzz: Any) -> list[Any]:
    """One boofuzz Request per client message of spec/nsqd.yaml (see the module docstring)."""
    rng = random.Random(0)
    out = []
    for m in NSQD.messages:
        if m.sent_by not in ("client", "any"):
            continue
        values = valid_values(NSQD, m, rng)
        body: list[Any] = [boofuzz.Byte(name="id", default_value=m.id)]
        for f in m.fields:
            t = NSQD.types[f.type]
            if "length" in t:
                body.append(boofuzz.Size(name=f"{f.name}_len", block_name=f"{f.name}_text", length=2, endian=">",
                                         signed=True, fuzzable=True))
                body.append(boofuzz.Block(name=f"{f.name}_text", children=(
                    boofuzz.String(name=f.name, default_value=str(values[f.name]), max_len=8192),)))
            elif t["struct"] == ">?":
                body.append(boofuzz.Byte(name=f.name, default_value=int(values[f.name])))
            else:
                body.append(boofuzz.DWord(name=f.name, default_value=int(values[f.name]) & 0xFFFFFFFF, endian=">"))
        out.append(boofuzz.Request(m.name, children=(
            boofuzz.Size(name="length", block_name="frame", length=4, endian=">", inclusive=True, signed=True,
                         fuzzable=True),
            boofuzz.Block(name="frame", children=tuple(body)),
        )))
    return out


def run_boofuzz(addr: tuple[str, int], cases: int, seconds: float, tuned: bool) -> tuple[int, float]:
    import boofuzz

    conn = boofuzz.TCPSocketConnection(addr[0], addr[1])
    kw: dict[str, Any] = {"target": boofuzz.Target(connection=conn), "index_end": cases, "sleep_time": 0.0}
    if tuned:
        kw.update(web_port=None, fuzz_loggers=[], fuzz_db_keep_only_n_pass_cases=1,
                  receive_data_after_each_request=False, receive_data_after_fuzz=False,
                  check_data_received_each_request=False)
    else:
        kw.update(web_port=web_port(), keep_web_open=False)
    return timed_session(boofuzz, kw, list(nsqd_requests(boofuzz)), seconds)


def _boofuzz_child(addr: tuple[str, int], cases: int, seconds: float, tuned: bool, pipe: Any) -> None:
    pipe.send(run_boofuzz(addr, cases, seconds, tuned))


def run_boofuzz_isolated(addr: tuple[str, int], cases: int, seconds: float, tuned: bool) -> tuple[int, float]:
    """``run_boofuzz`` in a process of its own: a Session's web UI thread (tornado) outlives it
    and would run beside the next row (and a second UI in one process fails to start)."""
    import multiprocessing

    ctx = multiprocessing.get_context("spawn")
    here, there = ctx.Pipe()
    proc = ctx.Process(target=_boofuzz_child, args=(addr, cases, seconds, tuned, there), daemon=True)
    proc.start()
    try:
        n, elapsed = here.recv()
    finally:
        proc.join(timeout=10)
        if proc.is_alive():
            proc.kill()
    return n, elapsed


def run_ours(command: str | None, addr: tuple[str, int] | None, engine: str, cases: int,
             seconds: float, probe_every: int = 40) -> tuple[int, float, int]:
    """mcp-fuzz's campaign: (cases, judged seconds, findings)."""
    c = StreamCampaign(addr, command, 20140307, seconds, cases, None, engine=engine, probe_every=probe_every)
    c.run()
    return c.cases, c.fuzz_s, len(c.findings)


class _Backend:
    """The backend for boofuzz's rows and mcp-fuzz's attached ones: one process, its stderr in
    a file. The reference backend runs with ``-v``: it logs each frame it parsed (handled or
    rejected) and each connection it accepted, so a row can say how much of what a tool sent
    the backend actually read (a blind sender's cases may die in the listen backlog)."""

    def __init__(self, command: str, verbose: bool) -> None:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = int(s.getsockname()[1])
        self.addr = ("127.0.0.1", port)
        self.log = tempfile.NamedTemporaryFile(prefix="bench-nsqd-", suffix=".log", delete=False)  # noqa: SIM115
        argv = shlex.split(command.format(target_host="127.0.0.1", target_port=port)) + (["-v"] if verbose else [])
        self.proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=self.log)
        self.verbose, self.seen = verbose, (0, 0)
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline:
            with socket.socket() as s, contextlib.suppress(OSError):
                s.settimeout(0.2)
                s.connect(self.addr)
                return
            time.sleep(0.05)
        self.stop()
        raise SystemExit(f"bench_fuzz: the backend did not listen: {command}")

    def read_since_last(self) -> str:
        """Frames parsed and connections accepted since the last call ('' when not logged)."""
        if not self.verbose:
            return ""
        time.sleep(0.3)  # what is still queued in the backend
        text = Path(self.log.name).read_text(errors="replace")
        frames = text.count("Handled(") + text.count("Rejected(")
        conns = text.count(" connected")
        d = (frames - self.seen[0], conns - self.seen[1])
        self.seen = (frames, conns)
        return f"  backend parsed {d[0]} frames on {d[1]} connections"

    def stop(self) -> None:
        self.proc.terminate()
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.proc.wait(timeout=2)
        self.proc.kill()
        self.proc.wait()
        self.log.close()
        os.unlink(self.log.name)


def listen_drops() -> int | None:
    """The kernel's count of connection attempts a full listen queue dropped (Linux, machine
    wide): each costs the client a SYN retransmission, 1 s, and shows as a stall in its row."""
    try:
        lines = [line.split() for line in Path("/proc/net/netstat").read_text().splitlines() if line.startswith("TcpExt:")]
        return int(lines[1][lines[0].index("ListenDrops")])
    except (OSError, ValueError, IndexError):
        return None


def _alive(addr: tuple[str, int]) -> bool:
    """The backend accepts and sends something within 2 s (after each tool's run)."""
    try:
        with socket.create_connection(addr, timeout=2) as s:
            s.settimeout(2)
            return bool(s.recv(64))
    except OSError:
        return False


def backends(which: str) -> list[tuple[str, str]]:
    out = []
    if which in ("reference", "both"):
        out.append(("Python reference backend", embedded_command()))
    if which in ("c", "both"):
        from tests.nsqd_backends.build import available, build

        why = available()
        if why:
            print(f"bench_fuzz: C backend skipped: {why}")
        else:
            for period in (0.05, 0.4):
                out.append((f"correct C backend (ASan), UPDATE every {period:g} s",
                            f"{build()} --host {{target_host}} --port {{target_port}} --update-period {period:g}"))
    return out


def main_nsqd(cases: int, seconds: float, which: str, engines: list[str], probe_every: int = 40) -> int:
    try:
        import boofuzz  # noqa: F401
        have_boofuzz = True
    except ImportError:
        have_boofuzz = False
        print(f"bench_fuzz: {BOOFUZZ_MISSING}")
    for label, command in backends(which):
        print(f"== {label}: {cases} cases or {seconds:g} s per row, whichever first", flush=True)
        backend = _Backend(command, verbose=command == embedded_command())
        addr = backend.addr
        rows: list[tuple[str, str, bool]] = []
        if have_boofuzz:
            rows += [("boofuzz 0.4.2 default", "", False), ("boofuzz 0.4.2 tuned", "", True)]
        rows += [(f"mcp-fuzz {e}, attached", e, False) for e in engines]
        try:
            backend.read_since_last()  # the liveness checks of the start
            for name, engine, tuned in rows:
                drops0 = listen_drops()
                if engine:
                    n, s, found = run_ours(None, addr, engine, cases, seconds, probe_every)
                else:
                    (n, s), found = run_boofuzz_isolated(addr, cases, seconds, tuned), None
                extra = "" if found is None else f"  findings: {found}"
                parsed = backend.read_since_last()
                drops1 = listen_drops()
                if drops0 is not None and drops1 is not None:
                    parsed += f"  listen drops {drops1 - drops0}"
                print(f"{name:34} {n:8d} cases in {s:6.2f} s  {n / s if s else 0:9,.0f} cases/s  "
                      f"live after: {_alive(addr)}{extra}{parsed}", flush=True)
                backend.read_since_last()  # the liveness check's own connection
        finally:
            backend.stop()
        for e in engines:  # process oracles on: its own process of the same command
            n, s, found = run_ours(command, None, e, cases, seconds, probe_every)
            print(f"{'mcp-fuzz ' + e + ', spawned':34} {n:8d} cases in {s:6.2f} s  {n / s if s else 0:9,.0f} "
                  f"cases/s  findings: {found}", flush=True)
    print(f"machine: {os.cpu_count()} CPUs, load average {' '.join(f'{x:.1f}' for x in os.getloadavg())}; "
          f"Python {sys.version.split()[0]}")
    return 0
