"""harness.manager_session: the mission files handed to the manager, the embedded
command and its placeholders (no sockets, no processes)."""

from __future__ import annotations

from mcp_conform.harness.drone_session import fill_placeholders
from mcp_conform.harness.manager_session import embedded_command, make_mission_items
from mcp_conform.spec.mission import load_waypoints, sane_item, save_waypoints


def test_mission_items_vary_with_the_seed_and_are_non_trivial():
    a, b = make_mission_items(1), make_mission_items(2)
    assert a != b and a == make_mission_items(1)
    for items in (a, b):
        assert 3 <= len(items) <= 6
        assert [it.seq for it in items] == list(range(len(items)))
        assert all(not sane_item(it) for it in items)
        assert all(it.x != 0 and it.y != 0 and it.z > 0 for it in items)
    many = [it for s in range(20) for it in make_mission_items(s)]
    assert len({it.command for it in many}) >= 4 and len({it.frame for it in many}) >= 2
    assert any(it.param1 or it.param2 or it.param3 or it.param4 for it in many)


def test_waypoint_file_round_trips_through_pymavlink(tmp_path):
    items = make_mission_items(7)
    path = tmp_path / "m.waypoints"
    save_waypoints(path, items)
    assert path.read_text().splitlines()[0] == "QGC WPL 110"
    back = load_waypoints(path)
    fields = ("seq", "current", "frame", "command", "param1", "param2", "param3", "param4", "x", "y", "z",
              "autocontinue")
    assert [tuple(getattr(it, f) for f in fields) for it in back] == \
           [tuple(getattr(it, f) for f in fields) for it in items]


def test_embedded_command_fills_every_manager_placeholder():
    argv = fill_placeholders(embedded_command(), {
        "challenge": "2", "drones": "1,2", "waypoints": "/w", "obstacles": "/o", "target_host": "127.0.0.1",
        "target_port": "1", "listen_host": "127.0.0.1", "listen_port": "2"})
    assert "{" not in " ".join(argv)
    assert argv[argv.index("--challenge") + 1] == "2" and argv[argv.index("--drones") + 1] == "1,2"
    assert argv[argv.index("--waypoints") + 1] == "/w" and argv[argv.index("--obstacles") + 1] == "/o"
    assert "mcp_conform.reference_impl" in argv and "manager" in argv
