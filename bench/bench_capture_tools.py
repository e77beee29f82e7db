"""mcp-capture show / diff / check / export on noisy captures, and check of a million violating datagrams.

    python bench/bench_capture_tools.py [--sizes 10000,20000,40000] [--million N] [--skip-million]
                                        [--only show,diff,check,export] [--golden] [--baseline SRC]

1. Noisy captures of 10k, 20k and 40k datagrams (tests/captures/noisy.py: unanswered drone
   commands, mutated copies, random bytes with random headers from several sources, runts):
   ``mcp-capture show``, ``diff`` (against another noisy capture of the same size),
   ``check --json`` and ``export --pcap`` (a .pcap and a .pcapng), each a subprocess: wall
   seconds, CPU seconds and peak RSS. Linear time doubles from one size to the next (issue 19
   item 7: 2.8 / 7.3 / 33 s for show before). ``--golden``: the same commands on
   captures/golden/drone-suite.mcap (10,286 datagrams) first.
2. ``mcp-capture check FILE --json OUT`` of a capture of ``--million`` datagrams, every one a
   violation (a drone sending WP_On to the manager, MCP-HDR-5): wall, CPU, peak RSS, against
   the issue's target of <= 60 s and <= 1 GB.

``--baseline SRC`` runs the same commands from another source tree as well (a checkout of an
older commit: ``git worktree add /tmp/old <rev>``), side by side. The captures are cached in
$TMPDIR. Figures only: nothing here asserts a timing.
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a source checkout

from mcp_conform.spec.codec import Action, Message, MissionItem, encode  # noqa: E402
from mcp_conform.traceio.recorder import McapRecorder  # noqa: E402
from tests.captures.noisy import write_noisy  # noqa: E402

ITEM = MissionItem(0.0, 0.0, 0.0, 0.0, 35.771103, -78.674659, 3.0, 1, 16, 1, 1, 3, 0, 1)
TARGET_S, TARGET_MB = 60.0, 1024.0


def cached(path: Path, make: object) -> Path:
    if not path.exists():
        part = path.with_suffix(".part")
        make(part)  # type: ignore[operator]
        part.replace(path)
    return path


#: Drones sending: each (drone, seq) once in 65,536 x DRONES datagrams (a repeated one would be
#: a copy of a message already judged, not a new violation).
DRONES = 64
#: One violating datagram a millisecond (1,000/s from 64 drones: 10^6 span about 17 minutes).
#: The monitor forgets messages past its horizon (60 s), so its memory is that of a minute of
#: traffic, and the violations' own that of every violation, which the JSON lists.
SPACING_NS = 1_000_000


def all_violating(path: Path, n: int) -> None:
    """``n`` WP_Ons from drones 1..64 to the manager: each one MCP-HDR-5 (a drone sends only
    Mission_Ready and ACK), none answered, no two with the same sender and seq.

    Written as ``McapRecorder.datagram`` writes them, byte for byte, without encoding and
    decoding each (``violating_bodies``): the generation is not what is measured."""
    if n > DRONES * 65536:
        raise ValueError(f"at most {DRONES * 65536} distinct violating datagrams")
    t = 1_800_000_000_000_000_000
    with McapRecorder(path, local=LOCAL) as rec:
        for i, body in enumerate(violating_bodies(n)):
            rec.write_encoded("/mcp/rx", body, t + i * SPACING_NS)


LOCAL = ("127.0.0.1", 7889)


def violating(i: int) -> tuple[bytes, tuple[str, int]]:
    """The ``i``-th violating datagram and its sender's address."""
    d = 1 + i % DRONES
    return encode(Message(0, d, i // DRONES, Action.WP_ON, ITEM)), ("127.0.0.1", 41000 + d)


def violating_bodies(n: int) -> Iterator[bytes]:
    """The JSON bodies ``McapRecorder.datagram("rx", *violating(i))`` writes, i < n: each
    drone's first body with its seq and raw bytes put in (they differ in nothing else; the
    first two of each drone are checked against the recorder's own)."""
    import base64

    from mcp_conform.traceio.recorder import datagram_record, encode_body

    parts = []
    for d in range(DRONES):
        raw, peer = violating(d)
        rec = datagram_record("rx", raw, peer, LOCAL)
        assert rec["seq"] == 0 and rec["raw_base64"] and rec["raw_hex"], rec
        rec.update(seq=987654321, raw_base64="@B64@", raw_hex="@HEX@")
        body = encode_body(rec)
        marks = sorted((body.index(m), m) for m in (b"987654321", b'"@B64@"', b'"@HEX@"'))
        assert all(body.count(m) == 1 for _, m in marks), body
        cut, pieces, kinds = 0, [], []
        for at, m in marks:
            pieces.append(body[cut:at])
            kinds.append(m)
            cut = at + len(m)
        pieces.append(body[cut:])
        seq_at = next(k for k in range(len(raw)) if raw[k] != violating(d + DRONES * 0x0102)[0][k])
        parts.append((raw[:seq_at], raw[seq_at + 2:], pieces, kinds))
    b64, hexed = base64.b64encode, bytes.hex
    for i in range(n):
        head, tail, pieces, kinds = parts[i % DRONES]
        seq = i // DRONES
        raw = head + seq.to_bytes(2, "big") + tail
        values = {b"987654321": str(seq).encode(), b'"@B64@"': b'"' + b64(raw) + b'"',
                  b'"@HEX@"': b'"' + hexed(raw).encode() + b'"'}
        body = pieces[0] + values[kinds[0]] + pieces[1] + values[kinds[1]] + pieces[2] + values[kinds[2]] + pieces[3]
        if i < 2 * DRONES:
            assert body == encode_body(datagram_record("rx", *violating(i), LOCAL)), i
        yield body


def run(src: Path, args: list[str]) -> tuple[float, float, float, int]:
    """(wall s, CPU s, peak RSS MB, exit code) of ``python -m mcp_conform.captures ARGS`` from ``src``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    code = subprocess.run([sys.executable, "-c",
                           "import resource, sys; from captures.cli import main; rc = main(sys.argv[1:]); "
                           "sys.stderr.write(f'\\nRSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}\\n'); "
                           "sys.exit(rc)", *args],
                          cwd=src, env={**os.environ, "PYTHONPATH": str(src)}, stdout=subprocess.DEVNULL,
                          stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    rss = next((int(line.split()[1]) / 1024 for line in code.stderr.splitlines() if line.startswith("RSS ")), 0.0)
    if code.returncode not in (0, 1):
        print(f"    ({' '.join(args[:1])} exit {code.returncode}: {code.stderr.strip()[-200:]})")
    return wall, cpu, rss, code.returncode


def row(label: str, trees: dict[str, Path], args: list[str]) -> None:
    cells = []
    for _name, src in trees.items():
        wall, cpu, rss, _ = run(src, args)
        cells.append(f"{wall:7.2f} s {cpu:7.2f} CPU {rss:6.0f} MB")
    print(f"  {label:22s}" + "   |".join(cells), flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="10000,20000,40000", help="noisy capture sizes (10000,20000,40000)")
    ap.add_argument("--million", type=int, default=1_000_000, help="violating datagrams in part 2 (1000000)")
    ap.add_argument("--skip-million", action="store_true", help="part 1 only")
    ap.add_argument("--only", default="show,diff,check,export",
                    help="the commands of part 1 (show,diff,check,export)")
    ap.add_argument("--golden", action="store_true", help="part 1's commands on the golden drone-suite capture too")
    ap.add_argument("--baseline", type=Path, help="another source tree to run side by side (an older commit)")
    args = ap.parse_args(argv)
    tmp = Path(os.environ.get("TMPDIR", "/tmp"))
    out = tmp / "bench-capture-tools.json"
    trees = {"this tree": ROOT, **({"baseline": args.baseline.resolve()} if args.baseline else {})}
    print(f"python {platform.python_version()} on {platform.machine()}, {os.cpu_count()} CPUs; "
          f"load {os.getloadavg()[0]:.1f}; columns: {', '.join(f'{k} ({v})' for k, v in trees.items())}")
    print("wall, CPU (user + system) and peak RSS of each command")
    only = set(args.only.split(","))
    inputs: list[tuple[str, Path, Path | None]] = []
    if args.golden:
        inputs.append(("golden drone-suite.mcap (10,286 datagrams)", ROOT / "captures" / "golden" / "drone-suite.mcap",
                       None))
    for n in (int(x) for x in args.sizes.split(",") if x):
        a = cached(tmp / f"bench-noisy-{n}.mcap", lambda p, n=n: write_noisy(p, n))
        b = cached(tmp / f"bench-noisy-{n}-other.mcap", lambda p, n=n: write_noisy(p, n, seed=7)) \
            if "diff" in only else None
        inputs.append((f"noisy capture of {n} datagrams", a, b))
    for title, a, b in inputs:
        print(f"{title}:")
        if "show" in only:
            row("show", trees, ["show", str(a)])
        if "diff" in only and b is not None:
            row("diff (another one)", trees, ["diff", str(a), str(b)])
        if "check" in only:
            row("check --json", trees, ["check", str(a), "--json", str(out)])
        if "export" in only:
            for suffix in ("pcap", "pcapng"):
                row(f"export --pcap .{suffix}", trees, ["export", str(a), "--pcap", str(tmp / f"bench-export.{suffix}")])
    if not args.skip_million:
        m = args.million
        cap = cached(tmp / f"bench-violating-{DRONES}-{SPACING_NS}-{m}.mcap", lambda p: all_violating(p, m))
        print(f"check --json of {m} datagrams, each a violation (target <= {TARGET_S:.0f} s, <= {TARGET_MB:.0f} MB):")
        for name, src in trees.items():
            wall, cpu, rss, code = run(src, ["check", str(cap), "--json", str(out)])
            verdict = "meets" if wall <= TARGET_S and rss <= TARGET_MB else "MISSES"
            size = out.stat().st_size / 1e6 if out.exists() else 0.0
            print(f"  {name:22s}{wall:7.2f} s {cpu:7.2f} CPU {rss:6.0f} MB  exit {code}, JSON {size:.0f} MB "
                  f"({verdict} the target)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
