"""``mcp-impair`` bounded and honest (issue 38 item 6): delayed copies wait in a queue with a
stated cap and a copy past it is dropped, recorded and counted, so a flood through a 60 s
delay with duplication cannot grow the proxy without bound; a ``--target`` host is resolved
once, at start (one line and exit 2 when it does not resolve)."""

from __future__ import annotations

import json
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from mcp_conform.harness.impair import (
    HELD_OVERHEAD,
    MAX_HELD_BYTES,
    DelayQueue,
    Impairment,
    parse_impairment,
)
from mcp_conform.harness.impair_proxy import ImpairProxy, main
from mcp_conform.vehicle.ports import free_port


def _kib(pid: int, field: str) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    raise AssertionError(f"no {field} in /proc/{pid}/status")


def test_the_queue_refuses_past_its_cap_in_copies_and_in_bytes() -> None:
    q: DelayQueue[int] = DelayQueue(max_count=3, max_bytes=10_000)
    assert all(q.push(5.0 - i, 100, i) for i in range(3))
    assert not q.push(1.0, 100, 99)  # a fourth copy: past the count
    assert q.pop_due(4.5) == [2, 1]  # due order
    big = 10_000 - q.held_bytes - HELD_OVERHEAD  # what still fits, to the byte
    assert not q.push(1.0, big + 1, 7) and q.push(1.0, big, 7)
    assert (q.refused, q.refused_bytes) == (2, 100 + big + 1)
    assert q.pop_due(10.0) == [7, 0] and q.held_bytes == 0


def test_a_refused_copy_is_recorded_as_a_queue_drop() -> None:
    """Through a proxy whose queue holds one copy: of a duplicated datagram one copy goes,
    the other is dropped, and the recorded decision says so."""
    class Rec:
        def __init__(self) -> None:
            self.decisions: list = []

        def impairment(self, decision, data, t_ns=None) -> None:
            self.decisions.append(decision)

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as far, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as c:
        far.bind(("127.0.0.1", 0))
        far.settimeout(5)
        rec = Rec()
        proxy = ImpairProxy(("127.0.0.1", 0), far.getsockname(),
                            Impairment(parse_impairment("dup=1,delay=50ms,seed=1")), recorder=rec,
                            max_held=1)
        t = threading.Thread(target=proxy.run, args=(time.monotonic() + 10,), daemon=True)
        t.start()
        try:
            c.sendto(b"hello", proxy.address)
            assert far.recv(64) == b"hello"
            far.settimeout(0.3)
            with pytest.raises(TimeoutError):
                far.recv(64)  # the second copy was refused
        finally:
            proxy.stop()
            t.join(5)
            proxy.close()
    (d,) = rec.decisions
    assert d.dropped == "queue" and len(d.deliveries) == 1
    assert json.loads(json.dumps(d.to_json()))["dropped"] == "queue"
    assert "1 dropped (1 queue)" in proxy.report() and "cap 1 copies" in proxy.report()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RSS from /proc is Linux's")
def test_a_flood_through_a_60_s_delay_with_duplication_stays_within_the_stated_cap() -> None:
    """The default cap (16 MiB of held copies): the proxy's peak RSS (VmHWM) over a flood of
    1,400-byte datagrams, each held ~60 s twice, stays under its RSS at start plus the cap
    plus 8 MiB (allocator slack). Before the cap the same flood grew it by ~100 MiB (57,642
    datagrams read in 4 s on a quiet host). The flood is bounded (60,000 datagrams or 6 s);
    the queue must have refused copies, and what the proxy read must have needed well over
    the bound without a cap, or the test could not fail and is skipped with the reason."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as far, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as c:
        far.bind(("127.0.0.1", 0))  # never read: nothing is due within the test anyway
        port = free_port()
        proc = subprocess.Popen([sys.executable, "-m", "mcp_conform.harness.impair_proxy", "--listen",
                                 f"127.0.0.1:{port}", "--target", f"127.0.0.1:{far.getsockname()[1]}",
                                 "--impair", "delay=59000-60000ms,dup=1,seed=5", "--duration", "60"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            assert proc.stdout is not None
            assert "delay=59000-60000ms" in proc.stdout.readline()  # listening
            baseline = _kib(proc.pid, "VmRSS")
            body = bytes(1396)
            end = time.monotonic() + 6.0
            for i in range(60_000):
                if time.monotonic() > end:
                    break
                c.sendto(i.to_bytes(4, "big") + body, ("127.0.0.1", port))
                if i % 20 == 19:
                    time.sleep(0.0005)  # let the proxy read: the kernel drops what it cannot
            time.sleep(0.5)
            peak = _kib(proc.pid, "VmHWM")
            proc.send_signal(signal.SIGINT)
            out, err = proc.communicate(timeout=30)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(10)
    assert proc.returncode == 130, err  # SIGINT: docs/grammar.md
    m = re.search(r"dropped \(([0-9]+) queue\)", out)
    assert m is not None and int(m.group(1)) > 0, f"the flood did not reach the cap: {out}"
    bound = MAX_HELD_BYTES + (8 << 20)
    up = int(re.search(r"([0-9]+) up", out).group(1))  # type: ignore[union-attr]
    if up * 2 * (1400 + HELD_OVERHEAD) < 1.5 * bound:
        pytest.skip(f"the proxy read only {up} datagrams of the flood on this host: without a cap "
                    f"they would not have held 1.5 times the bound, so the test cannot fail")
    grew = (peak - baseline) * 1024
    assert grew <= MAX_HELD_BYTES + (8 << 20), (
        f"grew {grew / (1 << 20):.1f} MiB over {baseline / 1024:.1f} MiB at start; "
        f"cap {MAX_HELD_BYTES >> 20} MiB; {out}")


def test_an_unresolvable_forward_host_is_one_line_exit_2(capsys) -> None:
    assert main(["--listen", "127.0.0.1:0", "--target", "nosuchhost.invalid:7"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("mcp-impair: error: --target")
    assert "nosuchhost.invalid" in err and "Traceback" not in err


def test_the_command_exits_2_without_a_traceback_on_an_unresolvable_host() -> None:
    r = subprocess.run([sys.executable, "-m", "mcp_conform.harness.impair_proxy", "--listen", "127.0.0.1:0",
                        "--target", "nosuchhost.invalid:7"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and len(r.stderr.splitlines()) == 1, r.stderr


def test_a_forward_name_is_resolved_once_to_an_address() -> None:
    """``localhost`` becomes its address at start: each datagram is sent to it, with no lookup."""
    try:
        want = socket.getaddrinfo("localhost", 7, socket.AF_INET, socket.SOCK_DGRAM)[0][4][0]
    except socket.gaierror:
        pytest.skip("localhost does not resolve on this host")
    proxy = ImpairProxy(("127.0.0.1", 0), ("localhost", 7), Impairment(parse_impairment("seed=0")))
    try:
        assert proxy.forward == (want, 7)
    finally:
        proxy.close()
