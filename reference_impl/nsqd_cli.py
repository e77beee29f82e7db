"""``mcp-node --protocol nsqd backend|client``: the reference Nsqd backend on a TCP port, or
a small client that connects to a backend, sends commands and prints what comes back.

::

    mcp-node --protocol nsqd backend [--listen HOST:PORT] [--update-period S] [-v|-q]
    mcp-node --protocol nsqd client --target HOST:PORT [--send NAME ...] [--duration S]

The backend prints ``listening on HOST:PORT`` once it listens, logs one line per event to
stderr and stops on SIGINT/SIGTERM (exit 130, 143: 128 + the signal's number), as the client does; a bad argument or a port in use is one line
and exit 2. The client prints each frame it receives as JSON, one per line. ``--bind`` and
``--connect`` are kept as deprecated aliases of ``--listen`` and ``--target`` (docs/grammar.md).
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import socket
import sys
import time
from collections.abc import Callable, Sequence
from typing import NoReturn

from mcp_conform.reference_impl.nsqd_backend import BackendCore, BackendServer
from mcp_conform.spec import NSQD
from mcp_conform.spec.nsqd_codec import BodyError, Deframer, FramingError, decode_body, encode
from mcp_conform.traceio.grammar import add_verbosity, deprecated, epilog

PROG = "mcp-node --protocol nsqd"
ERR = "mcp-node"  # errors' one prefix, as mcp-node's


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{ERR}: error: {message}\n")


def _hostport(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r} is not HOST:PORT")
    return host or "127.0.0.1", int(port)


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog=PROG, description="The reference Nsqd backend, or a client of one.",
                epilog=epilog("The backend stops on Ctrl-C or SIGTERM: exit 130 or 143 (128 + the signal's number)."),
                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="role", required=True)
    b = sub.add_parser("backend", help="serve the Nsqd protocol on a TCP port (one client at a time)")
    b.add_argument("--listen", type=_hostport, default=("127.0.0.1", NSQD.port("backend")), metavar="HOST:PORT",
                   help="where to listen")
    deprecated(b, "--bind", "--listen", type=_hostport)
    b.add_argument("--update-period", type=float, default=float(NSQD.params["update_period_s"]), metavar="S")
    add_verbosity(b, "one line per event on stderr", "errors only")
    c = sub.add_parser("client", help="connect to a backend, send commands, print what comes back")
    c.add_argument("--target", type=_hostport, default=("127.0.0.1", NSQD.port("backend")), metavar="HOST:PORT",
                   help="the backend's address")
    deprecated(c, "--connect", "--target", type=_hostport)
    c.add_argument("--send", nargs="*", default=[], metavar="NAME", help="commands without a body (TAKEOFF, LAND ...)")
    c.add_argument("--duration", type=float, default=2.0, metavar="S", help="how long to listen (2)")
    b.set_defaults(run=_backend)
    c.set_defaults(run=_client)
    for sp in (b, c):
        sp.epilog, sp.formatter_class = p.epilog, argparse.RawDescriptionHelpFormatter
    return p


def _backend(args: argparse.Namespace) -> int:
    if args.update_period <= 0:
        print(f"{ERR}: error: --update-period: must be > 0", file=sys.stderr)
        return 2
    level = logging.INFO if args.verbose else logging.ERROR if args.quiet else logging.WARNING
    logging.basicConfig(level=level, stream=sys.stderr,
                        format="%(name)s: %(message)s")
    try:
        server = BackendServer(*args.listen, core=BackendCore(update_period=args.update_period))
    except OSError as exc:
        print(f"{ERR}: error: --listen {args.listen[0]}:{args.listen[1]}: {exc.strerror}", file=sys.stderr)
        return 2
    stopped_by: list[int] = []

    def stop(signum: int, _frame: object) -> None:
        stopped_by.append(signum)
        server.stop()

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, stop)
    print(f"listening on {server.address[0]}:{server.address[1]}", flush=True)
    try:
        server.serve()
    finally:
        server.close()
    return 128 + stopped_by[0] if stopped_by else 0  # the grammar's interrupt: 130, 143


def _client(args: argparse.Namespace) -> int:
    for name in args.send:
        try:
            msg = NSQD.message(name.upper())
        except KeyError:
            print(f"{ERR}: error: --send: no message {name!r}", file=sys.stderr)
            return 2
        if msg.fields:
            print(f"{ERR}: error: --send: {msg.name} has a body; only bodiless commands are sent from here", file=sys.stderr)
            return 2
    try:
        sock = socket.create_connection(args.target, timeout=2.0)
    except OSError as exc:
        print(f"{ERR}: error: --target {args.target[0]}:{args.target[1]}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    deframer = Deframer(NSQD)
    stopped_by: list[int] = []

    def stop(signum: int, _frame: object) -> None:
        stopped_by.append(signum)
        raise _Stopped

    # its own handlers, as the backend's: Python's KeyboardInterrupt is not installed when the
    # shell started it with SIGINT ignored (a background job of a script), and SIGTERM's
    # default is no exit code of the grammar's
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, stop)
    try:
        return _listen(sock, deframer, args)
    except _Stopped:  # stopped while it listens: the grammar's interrupt (130, 143), no traceback
        return 128 + stopped_by[0]


class _Stopped(Exception):
    """SIGINT or SIGTERM arrived while the client listened."""


def _listen(sock: socket.socket, deframer: Deframer, args: argparse.Namespace) -> int:
    with sock:
        for name in args.send:
            sock.sendall(encode(NSQD, name.upper()))
        end = time.monotonic() + args.duration
        while (left := end - time.monotonic()) > 0:
            sock.settimeout(left)
            try:
                data = sock.recv(65536)
            except TimeoutError:
                break
            if not data:
                break
            for item in deframer.feed(data):
                if isinstance(item, FramingError):
                    print(json.dumps({"framing_error": item.reason}), flush=True)
                    return 1
                try:
                    values = decode_body(NSQD, item.msg_id, item.body, check_text=False).as_dict()
                    print(json.dumps({"id": item.msg_id, "name": NSQD.message(item.msg_id).name, **values}), flush=True)
                except (KeyError, BodyError) as exc:
                    print(json.dumps({"id": item.msg_id, "problem": str(exc)}), flush=True)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    run: Callable[[argparse.Namespace], int] = args.run  # the subcommand's (its parser's ``run``)
    return run(args)
