"""What the installed pytest plugin costs a pytest run that does not use it (issue 13).

Times ``pytest -q`` on one trivial test with the plugin as installed (inert: no --mcp-*
option) and with it disabled (``-p no:mcp_conform``), alternating, N rounds each, and prints
the medians side by side, then the same with an --mcp-* option (the runner loaded).
A figure, never a pass/fail gate: the machine is shared and noisy.

    python bench/bench_plugin_inert.py [ROUNDS]
"""

from __future__ import annotations

import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _time(args: list[str], cwd: Path) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *args],
                   cwd=cwd, check=True, capture_output=True)
    return time.perf_counter() - t0


def main() -> None:
    rounds = int(sys.argv[1]) if len(sys.argv) > 1 else 15
    with tempfile.TemporaryDirectory() as tmp:
        cwd = Path(tmp)
        (cwd / "test_plain.py").write_text("def test_ok():\n    assert True\n")
        runs: dict[str, list[float]] = {"disabled": [], "inert": [], "asked for": []}
        for _ in range(rounds):
            runs["disabled"].append(_time(["-p", "no:mcp_conform"], cwd))
            runs["inert"].append(_time([], cwd))
            runs["asked for"].append(_time(["--mcp-rto", "0.5"], cwd))
    base = statistics.median(runs["disabled"])
    print(f"pytest -q on one trivial test, median of {rounds} rounds (alternating):")
    for name, values in runs.items():
        med = statistics.median(values)
        print(f"  plugin {name:<10} {med * 1000:7.0f} ms   ({(med - base) * 1000:+5.0f} ms vs disabled)")


if __name__ == "__main__":
    main()
