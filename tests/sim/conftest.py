"""The simulator's tests (marker ``cpu``, tests/conftest.py): Python's cyclic garbage collector
kept off what a test did not make.

A simulated run allocates hundreds of thousands of short-lived objects (its nested pytest
session, the cases' threads on the virtual clock, the link's copies, the monitor's records), and
each of the collector's passes over the oldest generation walked, besides them, everything the
pytest worker holds (its session, the collected items, every imported module: some 120,000
objects). Measured in one process (``gc.callbacks`` around each pass): the 17 faulty-GCS runs
of tests/sim/test_mavlink_gcs_sim.py spent 1.0-1.2 s of their ~12 CPU s in the collector, 0.7
with the worker's objects frozen (``gc.freeze``) and the youngest generation collected every
10,000 net allocations instead of 700 (most of a run's objects are freed by their reference
counts before then); tests/sim/test_properties.py 2.6 -> 2.2 s of ~24. What the collector frees is
the same; only when it looks differs, and no verdict of the simulator depends on that (it keeps
no finalizer or weak reference that a case reads; bench/sim_report_check.py's 80 drone and mutant
reports, 8 seeds, are the same with these settings, switches and virtual times included).

Per test module, and put back after its last test: the tests of other modules find the collector
as it was (tests/traceio/test_check_cost.py checks that judging leaves nothing frozen). A worker
whose objects someone else froze (``gc.freeze``) keeps them frozen.
"""

from __future__ import annotations

import gc
from collections.abc import Iterator

import pytest

#: the youngest generation's threshold during a simulator test (CPython's default: 700)
YOUNG_THRESHOLD = 10_000


@pytest.fixture(autouse=True, scope="module")
def _collector_off_the_workers_objects() -> Iterator[None]:
    """The worker's objects frozen and the youngest generation's threshold raised for a test
    module (module docstring); both as they were after it, a failing test too."""
    freeze = gc.isenabled() and gc.get_freeze_count() == 0
    threshold = gc.get_threshold()
    if freeze:
        gc.freeze()
    gc.set_threshold(max(threshold[0], YOUNG_THRESHOLD), *threshold[1:])
    try:
        yield
    finally:
        gc.set_threshold(*threshold)
        if freeze:
            gc.unfreeze()
