"""Every reader against random and mutated files (issue 19: "a property test feeds random and
mutated MCAP, pcap, pcapng and waypoint files to every reader: no traceback, exit 0/1/2 only
as documented").

``mcp-capture check|show|export|diff`` read a capture (``captures.cli.main``, in process: an
exception that escapes it is the traceback a user would see); the exit code is 0 (read, no
violation or no difference), 1 (violations, differences) or 2 (the file could not be read: one line on stderr naming it).
The waypoint loader (every ``--waypoints`` option) returns items or raises
``WaypointFileError`` with one line naming the file.

``mcp-fuzz --seeds`` (``fuzz.campaign.load_seeds``) likewise.

The inputs: the golden captures, small pcap/pcapng/gzip files of MCP traffic and a pcap of
an Nsqd TCP conversation (read by the TCP reassembly and judged with the Nsqd rules), mutated by
hypothesis (bytes flipped, cut, inserted, slices repeated or dropped), and plain random bytes.
"""

from __future__ import annotations

import contextlib
import gzip
import io
import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mcp_conform.captures.cli import main as capture_main
from mcp_conform.spec.codec import Action, Message, encode
from mcp_conform.spec.mission import WaypointFileError, load_waypoints
from tests.tiers import examples

ROOT = Path(__file__).resolve().parents[2]
GOLDEN = ROOT / "captures" / "golden"
EXAMPLES = int(os.environ.get("MCP_PROPERTY_EXAMPLES", "40"))  # per reader and format (about a second each)


def _udp_frames() -> list[bytes]:
    from scapy.layers.inet import IP, UDP
    from scapy.layers.l2 import Ether

    msgs = [Message(1, 0, 10, Action.START_MISSION, None), Message(0, 1, 500, Action.ACK, 10),
            Message(0, 1, 501, Action.MISSION_READY, None)]
    return [bytes(Ether() / IP(src="127.0.0.1", dst="127.0.0.2") / UDP(sport=7889 + i % 2, dport=7890)
                  / encode(m)) for i, m in enumerate(msgs)]


def _pcap_bytes(ng: bool) -> bytes:
    import tempfile

    from scapy.layers.l2 import Ether
    from scapy.utils import PcapNgWriter, PcapWriter

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "seed"
        writer = (PcapNgWriter if ng else PcapWriter)(str(path))
        for i, frame in enumerate(_udp_frames()):
            pkt = Ether(frame)
            pkt.time = 1_700_000_000 + i * 0.1
            writer.write(pkt)
        writer.close()
        return path.read_bytes()


def _nsqd_pcap_bytes() -> bytes:
    """An Nsqd TCP conversation (handshake, frames both ways, a second connection, FIN) as
    ``mcp-capture export`` writes it: read back by the TCP reassembly and the Nsqd judge."""
    import tempfile

    from mcp_conform.traceio.reader import StreamFrame
    from mcp_conform.traceio.tcp_pcap import write_tcp_pcap
    from tests.traceio.test_nsqd_tcp import RPY, TAKEOFF, UP

    recs = [StreamFrame(0, 10**9, "tx", 5, "TAKEOFF", None, TAKEOFF),
            StreamFrame(1, 10**9 + 10, "rx", 5, "UPDATE", None, UP[0]),
            StreamFrame(2, 10**9 + 20, "tx", 6, None, None, RPY * 3),
            StreamFrame(3, 10**9 + 30, "rx", 5, "UPDATE", None, UP[1])]
    with tempfile.TemporaryDirectory() as d:
        write_tcp_pcap(Path(d) / "n.pcap", recs, 8888)
        return (Path(d) / "n.pcap").read_bytes()


SEEDS: dict[str, tuple[str, bytes]] = {}


def seed(kind: str) -> tuple[str, bytes]:
    """(file suffix, bytes) of a well-formed file of ``kind``."""
    if kind not in SEEDS:
        if kind == "mcap":
            SEEDS[kind] = (".mcap", (GOLDEN / "challenge1.mcap").read_bytes()[:60_000])
        elif kind == "pcap":
            SEEDS[kind] = (".pcap", _pcap_bytes(False))
        elif kind == "pcapng":
            SEEDS[kind] = (".pcapng", _pcap_bytes(True))
        elif kind == "pcap.gz":
            SEEDS[kind] = (".pcap.gz", gzip.compress(_pcap_bytes(False)))
        elif kind == "nsqd.pcap":
            SEEDS[kind] = (".pcap", _nsqd_pcap_bytes())
        elif kind == "waypoints":
            SEEDS[kind] = (".waypoints", (GOLDEN / "mission.waypoints").read_bytes())
    return SEEDS[kind]


@st.composite
def mutated(draw: st.DrawFn, data: bytes) -> bytes:
    """``data`` after up to 6 edits, or (sometimes) random bytes of a similar size."""
    if draw(st.integers(0, 9)) == 0:
        return draw(st.binary(max_size=min(len(data), 4096)))
    out = bytearray(data)
    for _ in range(draw(st.integers(1, 6))):
        op = draw(st.sampled_from(["flip", "cut", "insert", "repeat", "drop", "set"]))
        pos = draw(st.integers(0, max(0, len(out) - 1)))
        if op == "flip" and out:
            out[pos] ^= 1 << draw(st.integers(0, 7))
        elif op == "cut":
            del out[pos:]
        elif op == "insert":
            out[pos:pos] = draw(st.binary(min_size=1, max_size=64))
        elif op == "repeat":
            n = draw(st.integers(1, 256))
            out[pos:pos] = out[pos:pos + n]
        elif op == "drop":
            del out[pos:pos + draw(st.integers(1, 256))]
        elif op == "set" and len(out) >= pos + 4:
            # a length/count field set to an extreme
            out[pos:pos + 4] = draw(st.sampled_from([b"\xff\xff\xff\xff", b"\x7f\xff\xff\xff",
                                                     b"\x00\x00\x00\x00", b"\x00\x00\x00\x80"]))
    return bytes(out)


def _run_reader(argv: list[str]) -> tuple[int, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = capture_main(argv)
    return rc, err.getvalue()


def _judge_outcome(argv: list[str], path: Path) -> None:
    rc, err = _run_reader(argv)
    assert rc in (0, 1, 2), f"{argv}: exit {rc}\n{err[-2000:]}"
    if rc == 2:
        lines = [x for x in err.splitlines() if x.strip()]
        assert len(lines) == 1, f"{argv}: a reading error is one line, got:\n{err[-2000:]}"
        assert "Traceback" not in err


_SETTINGS = settings(max_examples=EXAMPLES, deadline=None, derandomize=True,
                     suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                                            HealthCheck.data_too_large])


@pytest.mark.parametrize("count", examples(full=EXAMPLES, quick=max(1, EXAMPLES // 4)))
@pytest.mark.parametrize("kind", ["mcap", "pcap", "pcapng", "pcap.gz", "nsqd.pcap"])
@pytest.mark.parametrize("command", ["check", "show", "export", "diff"])
def test_capture_readers_survive_mutated_files(kind: str, command: str, count: int, tmp_path: Path) -> None:
    suffix, data = seed(kind)

    @settings(_SETTINGS, max_examples=count)
    @given(mutated(data))
    def prop(blob: bytes) -> None:
        path = tmp_path / f"in{suffix}"
        path.write_bytes(blob)
        argv = {"check": ["check", str(path)],
                "show": ["show", str(path)],
                "export": ["export", str(path), "--pcap", str(tmp_path / "out.pcap")],
                "diff": ["diff", str(GOLDEN / "challenge1.mcap"), str(path)]}[command]
        _judge_outcome(argv, path)

    prop()


def test_the_seeds_are_read_cleanly(tmp_path: Path) -> None:
    """The unmutated seeds read with exit 0 or 1: the property above starts from files the
    readers accept, so its mutations reach past the first check."""
    for kind in ("mcap", "pcap", "pcapng", "pcap.gz", "nsqd.pcap"):
        suffix, data = seed(kind)
        path = tmp_path / f"seed{suffix}"
        path.write_bytes(data)
        rc, err = _run_reader(["show", str(path)])
        assert rc == 0, (kind, err)


@_SETTINGS
@given(mutated(seed("waypoints")[1]))
def test_the_waypoint_loader_survives_mutated_files(blob: bytes) -> None:
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "m.waypoints"
        path.write_bytes(blob)
        try:
            items = load_waypoints(path)
        except WaypointFileError as exc:
            text = str(exc)
            assert "\n" not in text and str(path) in text, text
        else:
            assert isinstance(items, tuple)


@pytest.mark.parametrize("suffix,rc", [(".pcap", 2), (".pcapng", 0)])
def test_export_refuses_a_time_the_output_cannot_hold(tmp_path: Path, suffix: str, rc: int) -> None:
    """Found by the property above (a pcapng whose if_tsresol was mutated): a datagram stamped
    past 2^32 s cannot go into a pcap's 32-bit seconds (scapy's struct.error escaped as a
    traceback); pcapng's 64-bit microseconds hold it."""
    from mcp_conform.traceio.recorder import McapRecorder

    path = tmp_path / "late.mcap"
    with McapRecorder(path, local=("127.0.0.1", 4000)) as rec:
        rec.datagram("tx", encode(Message(1, 0, 3, Action.WP_OFF, None)), ("127.0.0.1", 7890), 2**33 * 10**9)
    got, err = _run_reader(["export", str(path), "--pcap", str(tmp_path / f"out{suffix}")])
    assert got == rc, err
    if rc == 2:
        assert len(err.strip().splitlines()) == 1 and "outside what a pcap file's timestamp holds" in err, err
        assert not (tmp_path / f"out{suffix}").exists()


@_SETTINGS
@given(mutated(seed("mcap")[1]))
def test_the_fuzzers_seed_reader_survives_mutated_files(blob: bytes) -> None:
    """``mcp-fuzz --seeds DIR`` reads every MCAP under DIR: datagrams, or a one-line
    ``SetupError`` (exit 2) naming the file."""
    import tempfile

    from mcp_conform.fuzz.campaign import load_seeds
    from mcp_conform.harness.errors import SetupError

    with tempfile.TemporaryDirectory() as d:
        (Path(d) / "s.mcap").write_bytes(blob)
        try:
            got = load_seeds(d)
        except SetupError as exc:
            assert "\n" not in str(exc) and "--seeds" in str(exc), exc
        else:
            assert all(isinstance(x, bytes) and x for x in got)
