"""``mcp-impair``, the UDP proxy on the impairment schedule (issue 22 item 2): both
directions impaired, decisions reproducible by seed, each recorded on /impair, one-line
errors, a report of what it did."""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
import time

import pytest

from mcp_conform.harness.impair import Impairment, parse_impairment
from mcp_conform.harness.impair_proxy import ImpairProxy, main


def _echo() -> tuple[socket.socket, threading.Event, list[bytes]]:
    srv = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    srv.bind(("127.0.0.1", 0))
    srv.settimeout(0.05)
    stop = threading.Event()
    got: list[bytes] = []

    def serve() -> None:
        while not stop.is_set():
            try:
                data, addr = srv.recvfrom(65535)
            except (TimeoutError, OSError):
                continue
            got.append(data)
            srv.sendto(data, addr)

    threading.Thread(target=serve, daemon=True).start()
    return srv, stop, got


def _through(spec: str, n: int = 400, recorder=None) -> tuple[list[int], list[int], ImpairProxy]:
    """Send n numbered datagrams through a proxy to an echo server: (indexes the server got,
    indexes that came back)."""
    srv, stop, got = _echo()
    proxy = ImpairProxy(("127.0.0.1", 0), srv.getsockname(), Impairment(parse_impairment(spec)),
                        recorder=recorder)
    t = threading.Thread(target=proxy.run, args=(time.monotonic() + 30,), daemon=True)
    t.start()
    back: list[int] = []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as c:
        c.settimeout(0.05)
        for i in range(n):  # bounded in count; paced so the order of arrival is the order sent
            c.sendto(i.to_bytes(4, "big") + b"x" * 20, proxy.address)
            time.sleep(0.001)
        end = time.monotonic() + 0.4
        while time.monotonic() < end:
            try:
                back.append(int.from_bytes(c.recv(100)[:4], "big"))
            except TimeoutError:
                pass
    proxy.stop()
    t.join(5)
    proxy.close()
    stop.set()
    srv.close()
    return sorted(int.from_bytes(d[:4], "big") for d in got), back, proxy


@pytest.mark.slow
def test_both_directions_are_impaired_and_the_drops_replay_by_seed() -> None:
    up1, back1, p1 = _through("loss=0.3,seed=11")
    up2, back2, _ = _through("loss=0.3,seed=11")
    up3, _, _ = _through("loss=0.3,seed=12")
    assert up1 == up2 and sorted(back1) == sorted(back2)  # the same datagrams lost, both ways
    assert up1 != up3
    assert 0.6 < len(up1) / 400 < 0.8  # up: 30 % lost
    assert 0.4 < len(back1) / 400 < 0.6  # there and back: 1 - 0.7 ** 2 lost
    assert set(back1) <= set(up1)
    assert p1.per_direction == {"up": 400, "down": len(up1)}
    assert "dropped" in p1.report() and "up" in p1.report()


def test_duplication_and_reordering_reach_the_far_side() -> None:
    up, _, _ = _through("dup=0.3,reorder=0.3,delay=0-20ms,seed=4", n=200)
    assert len(up) > 230  # copies
    assert len(set(up)) == 200


def test_every_decision_is_recorded_on_impair(tmp_path) -> None:
    from mcp_conform.traceio.reader import open_capture  # noqa: F401  (the reader still reads the file)
    from mcp_conform.traceio.recorder import McapRecorder

    path = tmp_path / "link.mcap"
    with McapRecorder(path) as rec:
        _through("loss=0.5,seed=2", n=100, recorder=rec)
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        bodies = [m for _, c, m in make_reader(f, validate_crcs=True).iter_messages() if c.topic == "/impair"]
    import json

    records = [json.loads(m.data) for m in bodies]
    up = [r for r in records if r["direction"] == "up"]
    assert len(up) == 100 and any(r["dropped"] == "loss" for r in up)
    assert all(r["raw_base64"] for r in records)


@pytest.mark.parametrize(("argv", "words"), [
    (["--listen", "127.0.0.1:0", "--target", "127.0.0.1:9", "--loss", "2"], "probability"),
    (["--listen", "127.0.0.1:x", "--target", "127.0.0.1:9"], "--listen"),
    (["--listen", "127.0.0.1:0", "--target", "127.0.0.1:9", "--impair", "wobble=1"], "unknown key"),
])
def test_bad_options_are_one_line_exit_2(argv, words, capsys) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err


@pytest.mark.slow
def test_the_command_reports_what_it_did() -> None:
    """Started, fed 50 datagrams (each duplicated on the way), stopped by SIGINT once the far
    side has all 100: one line of what it did, exit 130 (``--duration`` only bounds the test
    should the signal be lost)."""
    import signal

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as far, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as c:
        far.bind(("127.0.0.1", 0))
        far.settimeout(30)
        from tests.capturing import free_port

        port = free_port()
        proc = subprocess.Popen([sys.executable, "-m", "mcp_conform.harness.impair_proxy", "--listen",
                                 f"127.0.0.1:{port}", "--target", f"127.0.0.1:{far.getsockname()[1]}",
                                 "--impair", "dup=1,seed=3", "--duration", "60"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            assert proc.stdout is not None
            first = proc.stdout.readline()  # printed once it listens
            assert "dup=1,seed=3" in first
            for i in range(50):
                c.sendto(bytes([i]), ("127.0.0.1", port))
            got = [far.recv(64) for _ in range(100)]  # every copy, or a timeout fails the test
            proc.send_signal(signal.SIGINT)
            out, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
    assert sorted(got) == sorted([bytes([i]) for i in range(50)] * 2)
    assert proc.returncode == 130, err
    assert "50 up" in out and "50 datagrams" in out and "50 duplicated" in out, out
