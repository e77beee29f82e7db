"""The runner's ``{mavlink}`` URL as the ``-v PORT`` / ``-l PORT`` / ``-H HOST`` options of a
seed-001-style UDP program (examples/mavlink_c/mavlink_udp.h), which then runs unchanged:

    python tests/mavlink/udp_args.py [--fixed-port N] URL PROGRAM [ARGS...]

- ``udpout:HOST:PORT`` (``--mavlink udpout``: the ground station sends to the runner's port):
  ``-H HOST -v PORT``, the program's "vehicle port";
- ``udpin:HOST:PORT`` (``--mavlink udp|udpin``: the runner sends to the ground station's port):
  ``-l PORT``, the program binds it and answers the first sender, as pymavlink's ``udpin:``.

Programs built on MAVLink 1 headers (mavgen ``--wire-protocol=1.0``, c_library_v1), whose
parser drops every MAVLink 2 frame, are run with the runner's own ``mcp-conform --mavlink1``:
its vehicle then speaks MAVLink 1 from the start, as ArduPilot on a port whose SERIALn_PROTOCOL
is 1. This wrapper re-packs nothing (its ``--mavlink1`` relay, which did, is gone: one line,
exit 2, naming the runner's option).

``--fixed-port N`` (with ``--mavlink udp``): for a program that listens on a port of its own
and takes no options (seed 001's upstream programs bind 14550), a relay on 127.0.0.1 stands
between the runner's URL and that port, every datagram passed on byte for byte both ways. It
lasts while the program runs, at most ``RELAY_MAX_S`` (and passes on what the program sent just
before it exited).

TCP is not something these programs speak: one line, exit 2.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import subprocess
import sys
import time

RELAY_MAX_S = 600.0
#: after the program exits, its datagrams still in the relay's socket are passed on for this long
DRAIN_S = 0.5


def split(url: str) -> tuple[str, str, int]:
    scheme, _, rest = url.partition(":")
    host, _, port = rest.rpartition(":")
    if not port.isdigit() or not host:
        raise ValueError(f"not a pymavlink URL with a host and port: {url!r}")
    if scheme not in ("udp", "udpin", "udpout"):
        raise ValueError(f"{scheme!r}: these programs speak UDP only (--mavlink udp or udpout)")
    return scheme, host, int(port)


def options(url: str) -> list[str]:
    """The program's options for the runner's URL; ValueError with the reason."""
    scheme, host, port = split(url)
    return ["-H", host, "-v", str(port)] if scheme == "udpout" else ["-l", str(port)]


def relay(url: str, argv: list[str], fixed_port: int) -> int:
    """Run ``argv``, which listens on ``fixed_port`` of its own, behind a relay from the
    runner's udp/udpin ``url``: every datagram passed on unchanged both ways; relay until it
    exits; its exit status."""
    _, host, port = split(url)
    near = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # the program's side
    near.bind(("127.0.0.1", 0))
    far = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # the runner's side: it sends to the relay
    far.bind((host, port))
    program = ("127.0.0.1", fixed_port)
    runner: tuple[str, int] | None = None
    proc = subprocess.Popen(argv)
    end = time.monotonic() + RELAY_MAX_S
    try:
        while proc.poll() is None and time.monotonic() < end:
            ready, _, _ = select.select([near, far], [], [], 0.1)
            if near in ready:
                data = near.recv(65535)
                if runner is not None:
                    far.sendto(data, runner)
            if far in ready:
                data, runner = far.recvfrom(65535)
                with contextlib.suppress(ConnectionRefusedError):  # not listening yet
                    near.sendto(data, program)
        drain = time.monotonic() + DRAIN_S  # what it sent just before it exited still goes
        while runner is not None and time.monotonic() < drain and select.select([near], [], [], 0.05)[0]:
            far.sendto(near.recv(65535), runner)
    finally:
        if proc.poll() is None:
            proc.terminate()
        near.close()
        far.close()
    return proc.wait(timeout=10)


def main(argv: list[str]) -> int:
    fixed = None
    if argv[:1] == ["--mavlink1"]:
        print("udp_args: --mavlink1 is the runner's now (mcp-conform --protocol mavlink --role gcs --mavlink1: "
              "its vehicle speaks MAVLink 1); this wrapper re-packs nothing", file=sys.stderr)
        return 2
    if argv[:1] == ["--fixed-port"] and len(argv) > 1 and argv[1].isdigit():
        fixed, argv = int(argv[1]), argv[2:]
    if len(argv) < 2:
        print("usage: udp_args.py [--fixed-port N] URL PROGRAM [ARGS...]", file=sys.stderr)
        return 2
    try:
        scheme = split(argv[0])[0]
        if fixed and scheme == "udpout":
            raise ValueError("--fixed-port goes with --mavlink udp (the program listens)")
    except ValueError as exc:
        print(f"udp_args: {exc}", file=sys.stderr)
        return 2
    prog, *args = argv[1:]
    try:
        if fixed:
            return relay(argv[0], [prog, *args], fixed)
        os.execv(prog, [prog, *options(argv[0]), *args])
    except OSError as exc:
        print(f"udp_args: cannot run {prog}: {exc.strerror}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
