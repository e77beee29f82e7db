"""Two runs of the same cases compare equal with ``mcp-capture diff``; an injected change does not.

Issue 35: ``mcp-capture diff`` of two runs of ``mcp-conform --select MCP-ACK`` differed in one
pair of three, on a Mav_Passthrough probe's token (``…-1-1323`` vs ``…-1-1322``: the runner
names a probe ``<case>-<n>-<the driver's next seq>``, and which seq that is depends on how the
batch's cases interleaved). Here several pairs of real runs against the embedded reference
drone with the simulated vehicle (``--mavlink``: MCP-ACK-5 then sends its probe to another ID,
in the batch beside MCP-ACK-4 and -6) are diffed by the command itself, then a copy of one
capture, rewritten with the project's own reader and writer, must differ and say where.

Not MCP-DUP here: its batch cases (DUP-1, DUP-4) send to the same node side by side, and where
one case's message falls among the other's in the manager's stream is the threads' race,
which the diff (rightly, so far) reads as a reordering; a golden of those is recorded
``--serial`` (captures/golden/README.md).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from captures.conversation import ProbeKey, probe_frame
from captures.diff import load_side
from spec.codec import Action, decode, encode
from tests.forkserver import run_module
from traceio.reader import Datagram, Metadata, open_capture
from traceio.recorder import McapRecorder
from vehicle.probe import make_probe

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
PAIRS = 3
#: the issue's run: MCP-ACK (ACK-5's probe to another ID, its token's seq set by the batch)
SELECT = ["MCP-ACK"]


def _record(path: Path) -> Path:
    proc = run_module("conformance", ["--select", *SELECT, "--mavlink", "--rto", "0.3",
                                      "--capture", str(path)], cwd=path.parent, timeout=180)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    return path


def _diff_cli(golden: Path, candidate: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "captures", "diff", str(golden), str(candidate)],
                          capture_output=True, text=True, timeout=120, cwd=ROOT, env=os.environ)


def _probes(path: Path) -> list[tuple[ProbeKey, str]]:
    """(normalised key, raw token) of each probe the runner sent, in capture order."""
    side = load_side(path)
    out = []
    for conv in side.conversations.values():
        for e in conv.entries:
            if isinstance(e.key[3], ProbeKey):
                found = probe_frame(e.payload)
                assert found is not None
                out.append((e.key[3], found[0]))
    return out


def _rewrite(src: Path, dst: Path, change) -> int:
    """Copy ``src``'s datagrams (and metadata) to ``dst`` through traceio's reader and
    recorder, ``change(datagram)`` returning new bytes or None; returns how many changed."""
    changed = 0
    with McapRecorder(dst) as rec:
        for r in open_capture(src):
            if isinstance(r, Metadata):
                rec.add_metadata(r.name, r.data)
            elif type(r) is Datagram:
                data = change(r)
                if data is not None:
                    changed += 1
                tx = r.direction == "tx"
                rec.datagram("tx" if tx else "rx", r.data if data is None else data,
                             r.dst_addr if tx else r.src_addr, r.t_ns,
                             local=r.src_addr if tx else r.dst_addr)
    return changed


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> list[Path]:
    d = tmp_path_factory.mktemp("golden-runs")
    return [_record(d / f"run{n}.mcap") for n in range(2 * PAIRS)]


def test_pairs_of_runs_of_the_same_cases_are_the_same(runs):
    stems = set()
    tokens = []
    for n in range(PAIRS):
        a, b = runs[2 * n], runs[2 * n + 1]
        proc = _diff_cli(a, b)
        assert proc.returncode == 0, f"pair {n}: {proc.stdout[-3000:]}{proc.stderr[-2000:]}"
        assert "same: every conversation matches" in proc.stdout
        pa, pb = _probes(a), _probes(b)
        assert len(pa) == len(pb) >= 1, (pa, pb)  # the comparison saw the probes
        stems |= {k.stem for k, _ in pa}
        tokens.append(sorted(t for _, t in pa))
    # ACK-5's probe to another ID, by the runner's naming (its token's seq may vary or not)
    assert any(s and "acted_on-1" in s for s in stems), (stems, tokens)


def test_a_probe_renamed_in_a_copy_of_a_run_differs(runs, tmp_path):
    """The copy as it is reads the same; with one probe's text changed to another case's
    probe, the diff exits 1 and names the probe's stem."""
    golden = runs[0]
    same = tmp_path / "copy.mcap"
    assert _rewrite(golden, same, lambda r: None) == 0
    proc = _diff_cli(golden, same)
    assert proc.returncode == 0, proc.stdout[-3000:]

    target: list[str] = []

    def rename(r: Datagram) -> bytes | None:
        msg = decode(r.data)
        if msg.action != Action.MAV_PASSTHROUGH or target:
            return None
        found = probe_frame(msg.payload)
        if found is None or "acted_on" not in found[0]:
            return None
        token = found[0]
        target.append(token)
        head, n, seq = token.rsplit("-", 2)
        return encode(msg._replace(payload=make_probe(f"{head}x-{n}-{seq}")))

    renamed = tmp_path / "renamed.mcap"
    assert _rewrite(golden, renamed, rename) == 1, "no MCP-ACK-5 probe in the capture"
    proc = _diff_cli(golden, renamed)
    assert proc.returncode == 1, proc.stdout[-3000:]
    assert "first divergence (changed)" in proc.stdout
    assert "payload.probe.stem" in proc.stdout and "MAV_PASSTHROUGH" in proc.stdout, proc.stdout


def test_an_mcp_field_changed_in_a_copy_of_a_run_differs(runs, tmp_path):
    """One ACK of the node's names another seq (MCP-ACK-2's field): exit 1, the ACK named."""
    golden = runs[1]
    done: list[int] = []

    def misack(r: Datagram) -> bytes | None:
        msg = decode(r.data)
        if done or msg.action != Action.ACK or msg.src == 0 or r.direction != "rx":
            return None
        done.append(msg.payload)
        return encode(msg._replace(payload=(msg.payload + 0x1000) & 0xFFFF))

    changed = tmp_path / "misacked.mcap"
    assert _rewrite(golden, changed, misack) == 1
    proc = _diff_cli(golden, changed)
    assert proc.returncode == 1, proc.stdout[-3000:]
    assert "1 divergence(s): 1 changed" in proc.stdout, proc.stdout
    first = proc.stdout.split("first divergence", 1)[1]
    assert "1→0 ACK of seq+" in first and "(no such message)" in first, proc.stdout
    assert "— payload: " in proc.stdout, proc.stdout  # the ACK's field, golden → candidate
