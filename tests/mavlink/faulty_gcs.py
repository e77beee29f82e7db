"""Faulty ground stations for the tests, as processes: the reference GCS
(``reference_impl.mavlink_gcs``) with one thing changed, so that ``mcp-conform --protocol
mavlink --role gcs`` must fail exactly the rule of that one thing. The faults are
``sim.gcs_faults``'s classes, which the simulator runs on its virtual clock too (one
definition each).

    python tests/mavlink/faulty_gcs.py --fault NAME URL [reference GCS options]

Faults: ``none`` (the reference itself) and each of ``sim.gcs_faults.FAULTS``, the rule it
breaks there (``RULES``).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run as a script from a checkout

from mcp_conform.reference_impl.mavlink_gcs import main  # noqa: E402
from mcp_conform.sim.gcs_faults import FAULTS  # noqa: E402

if __name__ == "__main__":
    args = sys.argv[1:]
    if len(args) < 2 or args[0] != "--fault" or args[1] not in FAULTS:
        print(f"usage: faulty_gcs.py --fault {'|'.join(FAULTS)} URL [options]", file=sys.stderr)
        raise SystemExit(2)
    raise SystemExit(main(["gcs", *args[2:]], gcs_class=FAULTS[args[1]]))
