"""CON — connections: accepting (NSQD-CON-1), one client at a time (NSQD-CON-2, D-4) and
connect/close cycles with the spawned backend's descriptors watched (NSQD-CON-3, E-7)."""

from __future__ import annotations

import time

from mcp_conform.conformance.marks import rules


@rules("NSQD-CON-1")
def test_backend_accepts_a_client(node):
    conn = node.open()
    node.check_stream(conn)


@rules("NSQD-CON-2")
def test_a_second_client_does_not_disturb_the_first(node):
    first = node.open()
    name, state = node.probe(first)
    node.settle(first, avoid=(state,))
    second = node.session.connect()
    since = time.monotonic()
    first.wait_for(lambda: len(first.updates(since)) >= 2, 2 * node.gap_max)
    first.send(node.encode(name))
    node.expect_state(first, (state,), since, "NSQD-CON-2", f"a second client connected, then {name} from the first")
    if first.closed_at is not None:
        raise node.fail("NSQD-CON-2", "the first client's connection kept", "the backend closed it")
    if second is None or second.closed_at is not None:
        return  # refused or closed: D-4 allows it
    first.close()
    node.session.conns.remove(first)
    ok = second.wait_for(lambda: bool(second.updates()) or second.closed_at is not None, node.gap_max + 0.5)
    node.check_stream(second)
    if not ok:
        raise node.fail("NSQD-CON-2", "the waiting second client served once the first left",
                        f"no UPDATE on it within {node.gap_max + 0.5:g} s of the first leaving")


@rules("NSQD-CON-3")
def test_connect_close_cycles(node):
    cycles = int(node.params["cycles"])
    node.open()
    time.sleep(0.2)
    before = node.session.open_fds()
    for c in list(node.session.conns):
        c.close()
    node.session.conns.clear()
    done = node.session.cycle_connections(cycles, within=20.0)
    node.expect_alive("NSQD-CON-3", f"{done} connect/close cycles")
    after = node.session.settled_fds()
    if done < cycles:
        raise node.fail("NSQD-CON-3", f"{cycles} connect/close cycles accepted within 20 s",
                        f"{done} cycles")
    if before is not None and after is not None and after - before > int(node.params["fd_growth_max"]):
        raise node.fail("NSQD-CON-3", f"open descriptors flat over {cycles} cycles (growth <= "
                        f"{int(node.params['fd_growth_max'])})", f"{before} before, {after} after")
