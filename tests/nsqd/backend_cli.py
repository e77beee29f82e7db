"""The command line of the tests' variant Nsqd backends (tests/nsqd/*_backend.py): ``--bind
HOST:PORT``, ``--update-period S`` and the variant's own options; the server made from them
says it listens, then serves."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from mcp_conform.reference_impl.nsqd_backend import BackendServer


def serve(make: Callable[[str, int, argparse.Namespace], BackendServer], *options: tuple[str, dict[str, Any]]) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--bind", required=True)
    ap.add_argument("--update-period", type=float, default=0.05)
    for flag, kw in options:
        ap.add_argument(flag, **kw)
    ns = ap.parse_args()
    host, _, port = ns.bind.rpartition(":")
    server = make(host, int(port), ns)
    print(f"listening on {host}:{port}", flush=True)
    server.serve()
