"""spec.mission: MISSION_ITEM conversion, QGC WPL 110 files through pymavlink, MCP-PAY-7 checks."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from hypothesis import given, settings
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mcp_conform.spec.codec import Action, Message, MissionItem, decode, encode
from mcp_conform.spec.mission import (
    WaypointFileError,
    from_mavlink,
    load_waypoints,
    sane_item,
    save_waypoints,
    to_mavlink,
)
from mcp_conform.spec.strategies import mission_items

# The description's Challenge 1 sample file ("Extracting WayPoint list"), its line wraps
# undone: one waypoint per line, 12 fields each.
SAMPLE = """QGC WPL 110
0 1 0 16 0 0 0 0 35.771332 -78.674421 0.000000 1
1 0 3 22 0.000000 0.000000 0.000000 0.000000 0.000000 0.000000 3.000000 1
2 0 3 19 5.000000 0.000000 0.000000 0.000000 35.771103 -78.674659 3.000000 1
3 0 3 19 5.000000 0.000000 0.000000 0.000000 35.771057 -78.674421 3.000000 1
4 0 3 20 0.000000 0.000000 0.000000 0.000000 0.000000 0.000000 0.000000 1
"""
#              p1   p2   p3   p4   x (lat, E-2)  y (lon)      z    seq cmd ts tc fr cur ac
EXPECTED = [
    MissionItem(0.0, 0.0, 0.0, 0.0, 35.771332, -78.674421, 0.0, 0, 16, 0, 0, 0, 1, 1),
    MissionItem(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 3.0, 1, 22, 0, 0, 3, 0, 1),
    MissionItem(5.0, 0.0, 0.0, 0.0, 35.771103, -78.674659, 3.0, 2, 19, 0, 0, 3, 0, 1),
    MissionItem(5.0, 0.0, 0.0, 0.0, 35.771057, -78.674421, 3.0, 3, 19, 0, 0, 3, 0, 1),
    MissionItem(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 4, 20, 0, 0, 3, 0, 1),
]


@pytest.fixture
def sample(tmp_path: Path) -> Path:
    path = tmp_path / "challenge1.txt"
    path.write_text(SAMPLE, encoding="ascii")
    return path


def test_sample_file_loads_item_by_item(sample: Path) -> None:
    items = load_waypoints(sample)
    assert len(items) == len(EXPECTED)
    for got, want in zip(items, EXPECTED, strict=True):
        assert got == want
    assert items[0].x == 35.771332 and items[0].y == -78.674421  # x is latitude (E-2)
    assert [i.command for i in items] == [
        mavlink2.MAV_CMD_NAV_WAYPOINT, mavlink2.MAV_CMD_NAV_TAKEOFF,
        mavlink2.MAV_CMD_NAV_LOITER_TIME, mavlink2.MAV_CMD_NAV_LOITER_TIME,
        mavlink2.MAV_CMD_NAV_RETURN_TO_LAUNCH]


def test_sample_items_are_sane_and_travel_in_a_wp_list(sample: Path) -> None:
    items = load_waypoints(sample)
    assert all(sane_item(i) == [] for i in items)
    data = encode(Message(1, 0, 1, Action.WP_LIST, items))
    assert len(data) == 17 + 2 + 37 * len(items)
    back = decode(data).payload
    for got, want in zip(back, items, strict=True):
        assert math.isclose(got.x, want.x, rel_tol=1e-7) and got.command == want.command


def test_save_then_load_round_trips(sample: Path, tmp_path: Path) -> None:
    items = load_waypoints(sample)
    out = tmp_path / "saved.txt"
    save_waypoints(out, items)
    assert out.read_text().splitlines()[0] == "QGC WPL 110"
    assert load_waypoints(out) == items


def test_save_keeps_each_items_seq(tmp_path: Path) -> None:
    items = [EXPECTED[2]._replace(seq=7), EXPECTED[3]._replace(seq=9)]
    out = tmp_path / "seq.txt"
    save_waypoints(out, items)
    assert [i.seq for i in load_waypoints(out)] == [7, 9]


@pytest.mark.parametrize(("text", "line", "words"), [
    ("QGC WPL 100\n", 1, "QGC WPL 110"),
    ("", 1, "QGC WPL 110"),
    ("QGC WPL 110\n0 1 0 16 0 0 0 0 35.771332 -78.674421\n0.000000 1\n", 2, "10 fields"),
    ("QGC WPL 110\n# comment\n0 1 0 x 0 0 0 0 1 2 3 1\n", 3, "command 'x'"),
    ("QGC WPL 110\n0 1 0 16 0 0 0 0 lat 2 3 1\n", 2, "field 9"),
    ("QGC WPL 110\n0 1 300 16 0 0 0 0 1 2 3 1\n", 2, "frame 300"),
])
def test_bad_files_name_the_file_and_line(tmp_path: Path, text: str, line: int, words: str) -> None:
    path = tmp_path / "bad.txt"
    path.write_text(text, encoding="ascii")
    with pytest.raises(WaypointFileError) as info:
        load_waypoints(path)
    msg = str(info.value)
    assert isinstance(info.value, ValueError)
    assert msg.startswith(f"{path}:{line}: ") and words in msg and "\n" not in msg


def test_missing_and_binary_files(tmp_path: Path) -> None:
    with pytest.raises(WaypointFileError, match="cannot read"):
        load_waypoints(tmp_path / "absent.txt")
    blob = tmp_path / "blob.txt"
    blob.write_bytes(b"QGC WPL 110\n\xff\xfe")
    with pytest.raises(WaypointFileError, match="not a text file"):
        load_waypoints(blob)


def test_to_and_from_mavlink() -> None:
    msg = to_mavlink(EXPECTED[2])
    assert msg.get_type() == "MISSION_ITEM"
    assert (msg.x, msg.y, msg.command, msg.frame) == (35.771103, -78.674659, 19, 3)
    assert from_mavlink(msg) == EXPECTED[2]
    packed = msg.pack(mavlink2.MAVLink(None))
    parsed = mavlink2.MAVLink(None).parse_buffer(packed)[0]
    back = from_mavlink(parsed)
    assert back.command == 19 and math.isclose(back.x, 35.771103, rel_tol=1e-7)


def test_from_mavlink_refuses_other_messages() -> None:
    with pytest.raises(ValueError, match="HEARTBEAT"):
        from_mavlink(mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
    with pytest.raises(ValueError, match="not a MISSION_ITEM"):
        from_mavlink(object())


@settings(max_examples=60, deadline=None)
@given(mission_items())
def test_mavlink_conversion_round_trips(item: MissionItem) -> None:
    assert from_mavlink(to_mavlink(item)) == item


@pytest.mark.parametrize(("change", "problem"), [
    ({"x": 91.0}, "latitude"),
    ({"y": -180.5}, "longitude"),
    ({"z": float("nan")}, "z is not a finite"),
    ({"param1": float("inf")}, "param1"),
    ({"command": 9999}, "command 9999"),
    ({"frame": 99}, "frame 99"),
])
def test_sane_item_reports_pay7_problems(change: dict[str, float], problem: str) -> None:
    problems = sane_item(EXPECTED[2]._replace(**change))
    assert len(problems) == 1 and problem in problems[0]


def test_sane_item_checks_degrees_only_in_global_frames() -> None:
    local = EXPECTED[2]._replace(frame=mavlink2.MAV_FRAME_LOCAL_NED, x=500.0, y=-900.0)
    assert sane_item(local) == []
    assert sane_item(local._replace(frame=mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT)) != []


# ---------------------------------------------------------------- hostile waypoint files (issue 19)
def _wpl(n: int, lat: str = "35.7") -> str:
    rows = [f"{i}\t0\t3\t16\t0\t0\t0\t0\t{lat}\t-78.6\t10\t1" for i in range(n)]
    return "QGC WPL 110\n" + "\n".join(rows) + "\n"


def test_non_regular_files_are_refused_without_reading(tmp_path: Path) -> None:
    import os

    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)  # reading it would block for ever
    from mcp_conform.spec.mission import WaypointFileError, load_waypoints

    for path in ("/dev/zero", str(tmp_path), str(fifo)):
        with pytest.raises(WaypointFileError, match="not a regular file"):
            load_waypoints(path)


def test_values_the_wire_cannot_carry_and_lists_one_datagram_cannot_hold(tmp_path: Path) -> None:
    from mcp_conform.spec.mission import MAX_LIST_ITEMS, WaypointFileError, load_waypoints

    big = tmp_path / "big.waypoints"
    big.write_text(_wpl(2, lat="1e39"))
    with pytest.raises(WaypointFileError, match=r"big.waypoints:2: field 9 1e39 does not fit"):
        load_waypoints(big)
    many = tmp_path / "many.waypoints"
    many.write_text(_wpl(MAX_LIST_ITEMS + 1))
    with pytest.raises(WaypointFileError, match=f"{MAX_LIST_ITEMS + 1} waypoints: .* at most 1769"):
        load_waypoints(many)
    full = tmp_path / "full.waypoints"
    full.write_text(_wpl(MAX_LIST_ITEMS))
    assert len(load_waypoints(full)) == MAX_LIST_ITEMS == 1769
    huge = tmp_path / "huge.waypoints"
    with open(huge, "wb") as f:
        f.truncate(10**9)  # sparse: 1 GB said, nothing read
    with pytest.raises(WaypointFileError, match="larger than a waypoint list"):
        load_waypoints(huge)


@pytest.mark.parametrize("path", ["/dev/zero", "1e39"])
def test_mcp_capture_refuses_a_hostile_waypoints_file_in_one_line(tmp_path: Path, path: str) -> None:
    """Under a 2 GiB address-space limit, one line and exit 2 (it read /dev/zero whole). The
    limit is set by util-linux's prlimit(1), which execs the command: no ``preexec_fn`` in a
    pytest worker that may run threads (documented unsafe)."""
    import shutil
    import subprocess
    import sys

    prlimit = shutil.which("prlimit")
    if prlimit is None:
        pytest.skip("no prlimit(1): the address-space limit cannot be set")

    if path == "1e39":
        path = str(tmp_path / "bad.waypoints")
        Path(path).write_text(_wpl(3, lat="1e39"))
    golden = Path(__file__).resolve().parents[2] / "captures" / "golden" / "challenge1.mcap"

    limit = f"--as={2 << 30}:{2 << 30}"
    proc = subprocess.run([prlimit, limit, "--", sys.executable, "-m", "mcp_conform.captures", "check", str(golden),
                           "--waypoints", path], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and "--waypoints" in proc.stderr, proc.stderr
