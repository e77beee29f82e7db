"""A property test's example count in each tier (issue 38 item 4: the README's quick run, ``-m
"not slow and not cpu"``, within 60 s on CI's 2 cores).

``examples(full, quick)`` parametrizes a property test twice: ``[quick]`` with ``quick``
examples, in the quick run (enough to catch a property broken outright, at once, on every
change); ``[full]`` with ``full``, the count the test had, marked ``cpu`` (pure computation:
CI runs it niced beside the slow tests, on the CPU those leave idle while they wait on protocol
timers, ``.ci/run``). Nothing is dropped: the search the test made before still runs in CI.
"""

from __future__ import annotations

import pytest


def examples(full: int, quick: int) -> list:
    """``pytest.mark.parametrize``'s values for an example count: ``quick`` unmarked, ``full``
    marked ``cpu``."""
    assert 0 < quick <= full
    return [pytest.param(quick, id="quick"), pytest.param(full, id="full", marks=pytest.mark.cpu)]
