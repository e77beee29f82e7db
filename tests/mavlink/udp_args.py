"""The runner's ``{mavlink}`` URL as the ``-v PORT`` / ``-l PORT`` / ``-H HOST`` options of a
seed-001-style UDP program (examples/mavlink_c/mavlink_udp.h), which then runs unchanged:

    python tests/mavlink/udp_args.py [--mavlink1] URL PROGRAM [ARGS...]

- ``udpout:HOST:PORT`` (``--mavlink udpout``: the ground station sends to the runner's port):
  ``-H HOST -v PORT``, the program's "vehicle port";
- ``udpin:HOST:PORT`` (``--mavlink udp|udpin``: the runner sends to the ground station's port):
  ``-l PORT``, the program binds it and answers the first sender, as pymavlink's ``udpin:``.

``--mavlink1``: the program was built on MAVLink 1 headers (mavgen
``--wire-protocol=1.0``, c_library_v1), whose parser drops every MAVLink 2 frame, and the
runner's vehicle speaks MAVLink 2 only; ArduPilot answers such a link in MAVLink 1 when its
SERIALn_PROTOCOL is 1 (vehicle/codec.py's ``Encoder`` does the same). A relay on 127.0.0.1
then stands between them: the program's datagrams go to the runner byte for byte (what the
runner judges is what the program sent), the runner's frames go to the program re-packed in
MAVLink 1 (same source IDs and sequence numbers; a message MAVLink 1 cannot carry is dropped).
It lasts while the program runs, at most ``RELAY_MAX_S`` (and passes on what the program
sent just before it exited). Over udpout the program sends to
the relay (``-v``); over udp/udpin the runner sends to the relay, which sends to the program's
port (``-l``, or ``--fixed-port N`` for a program that listens on a port of its own, with no
options: seed 001's upstream programs bind 14550).

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


def relay(url: str, argv: list[str], fixed_port: int | None = None) -> int:
    """Run ``argv`` behind the relay (``-H 127.0.0.1 -v PORT`` for udpout, ``-l PORT`` for
    udpin, nothing when it listens on ``fixed_port`` of its own); relay until it exits; its
    exit status."""
    from pymavlink.dialects.v10 import ardupilotmega as v1
    from pymavlink.dialects.v20 import ardupilotmega as v2

    from mcp_conform.vehicle.ports import free_port

    scheme, host, port = split(url)
    near = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # the program's side
    near.bind(("127.0.0.1", 0))
    far = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # the runner's side
    runner: tuple[str, int] | None = None
    program: tuple[str, int] | None = None
    if scheme == "udpout":  # the program sends first, to the relay; the relay to the runner
        far.bind(("127.0.0.1", 0))
        runner, opts = (host, port), ["-H", "127.0.0.1", "-v", str(near.getsockname()[1])]
    else:  # the runner sends first, to the relay; the relay to the program's port
        far.bind((host, port))
        program = ("127.0.0.1", fixed_port or free_port("127.0.0.1"))
        opts = [] if fixed_port else ["-l", str(program[1])]
    parser = v2.MAVLink(None)
    parser.robust_parsing = True
    proc = subprocess.Popen([argv[0], *opts, *argv[1:]])
    end = time.monotonic() + RELAY_MAX_S
    try:
        while proc.poll() is None and time.monotonic() < end:
            ready, _, _ = select.select([near, far], [], [], 0.1)
            if near in ready:
                data, program = near.recvfrom(65535)
                if runner is not None:
                    far.sendto(data, runner)
            if far in ready:
                data, runner = far.recvfrom(65535)
                for msg in parser.parse_buffer(data) or []:
                    cls = getattr(v1, type(msg).__name__, None)
                    if cls is None or program is None:
                        continue
                    enc = v1.MAVLink(None, srcSystem=msg.get_srcSystem(), srcComponent=msg.get_srcComponent())
                    enc.seq = msg.get_seq()
                    values = [getattr(msg, n) for n in cls.fieldnames]
                    values = [v.encode("latin-1", "replace") if isinstance(v, str) else v for v in values]
                    with contextlib.suppress(ConnectionRefusedError):  # not listening yet
                        near.sendto(bytes(cls(*values).pack(enc)), program)
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
    mavlink1, fixed = False, None
    while argv[:1] in (["--mavlink1"], ["--fixed-port"]):
        if argv[0] == "--mavlink1":
            mavlink1, argv = True, argv[1:]
        elif len(argv) > 1 and argv[1].isdigit():
            fixed, argv = int(argv[1]), argv[2:]
        else:
            break
    if len(argv) < 2:
        print("usage: udp_args.py [--mavlink1 [--fixed-port N]] URL PROGRAM [ARGS...]", file=sys.stderr)
        return 2
    try:
        scheme = split(argv[0])[0]
        if fixed and (not mavlink1 or scheme == "udpout"):
            raise ValueError("--fixed-port goes with --mavlink1 and --mavlink udp (the program listens)")
    except ValueError as exc:
        print(f"udp_args: {exc}", file=sys.stderr)
        return 2
    prog, *args = argv[1:]
    try:
        if mavlink1:
            return relay(argv[0], [prog, *args], fixed)
        os.execv(prog, [prog, *options(argv[0]), *args])
    except OSError as exc:
        print(f"udp_args: cannot run {prog}: {exc.strerror}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
