"""The golden scenarios, recorded: ``python -m mcp_conform.captures.scenarios challenge N OUT.mcap``.

A challenge scenario is the reference Mission Manager (``mcp-node manager``) running
challenge N (1: WP_List, 2: WP_On/WP_Off, 3: Obstacles_List) with two reference drones
(``mcp-node drone``, IDs 1 and 2), all on loopback with free ports, the drones sharing one
port and the manager's loopback broadcasts as the description runs them (MCP-TRN-1). The
manager records the run (``--capture``): its view holds both conversations, 0 ↔ 1 and
0 ↔ 2. The manager starts first (a drone takes longer to reach its Mission_Ready), with
``--rto 0.5`` so a loaded host does not add retransmissions. Mission inputs are the files
beside the golden captures (captures/golden/mission.waypoints, obstacles.waypoints).

The drone-role scenario is the runner against the embedded reference drone:
``mcp-conform --capture OUT.mcap`` (see captures/golden/README.md).
"""

from __future__ import annotations

import contextlib
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from mcp_conform.vehicle.ports import free_port

__all__ = ["GOLDEN", "record_challenge"]

GOLDEN = Path(__file__).resolve().parent / "golden"
DRONES = (1, 2)
RTO = 0.5


def _free_port() -> int:
    return free_port("127.0.0.1", socket.SOCK_DGRAM)  # reserved host-wide (vehicle.ports)


def record_challenge(challenge: int, out: str | Path, *, rto: float = RTO, timeout: float = 60.0) -> None:
    """Run challenge ``challenge`` between the reference manager and drones 1 and 2 and
    record the manager's capture to ``out``; RuntimeError (one line) when the run fails."""
    node = [sys.executable, "-m", "mcp_conform.reference_impl"]
    manager_port, drone_port = _free_port(), _free_port()
    broadcast = "127.255.255.255"
    manager = subprocess.Popen(
        node + ["manager", "--challenge", str(challenge), "--drones", ",".join(map(str, DRONES)),
                "--waypoints", str(GOLDEN / "mission.waypoints"), "--obstacles", str(GOLDEN / "obstacles.waypoints"),
                broadcast, str(manager_port), str(drone_port), "--rto", str(rto), "--capture", str(out)],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    drones: list[subprocess.Popen[bytes]] = []
    try:
        deadline = time.monotonic() + timeout
        for d in DRONES:  # a drone takes longer to start (its vehicle, the GPS fix) than the manager
            drones.append(subprocess.Popen(
                node + ["drone", "--id", str(d), broadcast, str(drone_port), str(manager_port), "--rto", str(rto),
                        "--reuse-port", "-q"],
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        try:
            _, err = manager.communicate(timeout=max(1.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            raise RuntimeError(f"challenge {challenge}: the manager did not finish within {timeout:g} s") from None
        if manager.returncode != 0:
            raise RuntimeError(f"challenge {challenge}: the manager exited with {manager.returncode}: "
                               f"{(err or '').strip().splitlines()[-1:] }")
    finally:  # the capture is the manager's: the drones need not finish their RTL
        procs: list[subprocess.Popen[Any]] = [manager, *drones]
        for p in procs:
            if p.poll() is None:
                p.terminate()
        for p in procs:
            with contextlib.suppress(subprocess.TimeoutExpired):
                p.wait(timeout=5)
            if p.poll() is None:
                p.kill()
                p.wait()


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 3 or args[0] != "challenge" or args[1] not in ("1", "2", "3"):
        print("usage: python -m mcp_conform.captures.scenarios challenge {1,2,3} OUT.mcap", file=sys.stderr)
        return 2
    try:
        record_challenge(int(args[1]), args[2])
    except RuntimeError as exc:
        print(f"captures.scenarios: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {args[2]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
