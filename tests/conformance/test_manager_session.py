"""harness.manager_session: the mission files handed to the manager, the embedded
command and its placeholders (no sockets, no processes)."""

from __future__ import annotations

from harness.manager_session import embedded_command, make_mission_items
from harness.session import fill_placeholders
from spec.mission import load_waypoints, sane_item, save_waypoints


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
    assert "reference_impl" in argv and "manager" in argv


# ---------------------------------------------------------------------- the withheld Start_Mission's watch
def test_the_watch_after_the_right_start_ack_runs_on_beside_the_mission_s_end():
    """The watch for Start_Mission copies after the right ACK (MCP-RTX-1) no longer holds up
    the wait for the mission's end (issue 23: it runs on beside it): the end is awaited from
    the right ACK, but not given up before the watch's end, and only the copies within the
    watch count."""
    import time

    from harness.driver import Datagram, Sent, read_header
    from harness.manager_mission import Mission, MissionScript
    from spec.codec import Action, Message, encode

    now = time.monotonic()
    start = encode(Message(1, 0, 77, Action.START_MISSION, None))
    rx = [Datagram(n, now + t, 0, start, ("127.0.0.1", 9), None, None, read_header(start))
          for n, t in enumerate((0.1, 0.5))]  # a copy within the watch, one after it

    class Drv:
        def received(self, since=0, until=None):
            return [d for d in rx[since:until] if d.t <= time.monotonic()]

        def mark(self):
            return len(rx)

        def wait_for(self, pred, timeout, since=0):
            time.sleep(timeout)

    class Players:
        acked_actions = {1: {int(Action.END_MISSION)}}  # the mission has ended already

    m = Mission("main", (1,), 1, None, None)
    m.withheld.drone = 1
    m.withheld.right_ack = Sent(now, 0, b"", ("127.0.0.1", 9), 1, 0, 77, int(Action.ACK))
    script = MissionScript(Drv(), Players(), m, rto=0.05, ack_window=0.05, broadcast_id=0xFFFF, seed=0,
                           alive=lambda: True, ready_limit=1.0)
    script._watch_end = now + 0.3
    script._await_end()
    assert time.monotonic() >= now + 0.3 and m.ended_by == "end_mission"
    script._close_watch()
    assert [round(d.t - now, 1) for d in m.withheld.copies_after_right_ack] == [0.1]
