"""Benchmark the simulated vehicle: model frames/s and probe frames/s over loopback TCP.

Run: ``python bench/bench_vehicle.py`` (from a checkout or with the package installed). Prints figures only; nothing is asserted.
"""

from __future__ import annotations

import socket
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout

from mcp_conform.vehicle import Decoder, SimVehicle, VehicleConfig, VehicleModel, make_probe


def bench_model(n: int = 20000) -> float:
    """Decoded probe frames handled per second by the sans-I/O model (decode included)."""
    model = VehicleModel(VehicleConfig(max_records=n), now=0.0)
    data = b"".join(make_probe(f"p{i % 100}", seq=i % 256) for i in range(n))
    start = time.perf_counter()
    msgs, _, _ = Decoder().feed(data)
    for i, m in enumerate(msgs):
        model.handle(m, i * 1e-6)
    elapsed = time.perf_counter() - start
    assert sum(model.probe_tokens().values()) == n
    return n / elapsed


def bench_tcp(n: int = 5000) -> float:
    """Probe frames per second from a raw TCP client until all are counted."""
    with SimVehicle(max_records=n + 1000) as v:
        assert v.port is not None
        sock = socket.create_connection(("127.0.0.1", v.port))
        frames = [make_probe("tcp", seq=i % 256) for i in range(n)]
        start = time.perf_counter()
        for f in frames:
            sock.sendall(f)
        ok = v.wait_for(lambda: v.probe_count("tcp") == n, 60)
        elapsed = time.perf_counter() - start
        sock.close()
        if not ok:
            raise SystemExit(f"only {v.probe_count('tcp')} of {n} probes counted")
    return n / elapsed


def main() -> None:
    print(f"model: {bench_model():,.0f} frames/s (decode + handle + record)")
    print(f"tcp:   {bench_tcp():,.0f} probe frames/s over loopback")


if __name__ == "__main__":
    main()
