"""A property test's example count in each tier (issue 38 item 4: the README's quick run, ``-m
"not slow and not cpu"``, within 60 s on CI's 2 cores).

``examples(full, quick)`` parametrizes a property test twice: ``[quick]`` with ``quick``
examples, in the quick run (enough to catch a property broken outright, at once, on every
change); ``[full]`` with ``full``, the count the test had, marked ``cpu`` (pure computation:
CI runs it niced beside the slow tests, on the CPU those leave idle while they wait on protocol
timers, ``.ci/run``). Nothing is dropped: the search the test made before still runs in CI.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest


def examples(full: int, quick: int) -> list:
    """``pytest.mark.parametrize``'s values for an example count: ``quick`` unmarked, ``full``
    marked ``cpu``."""
    assert 0 < quick <= full
    return [pytest.param(quick, id="quick"), pytest.param(full, id="full", marks=pytest.mark.cpu)]


def tiered_property(full: int, quick: int, *strategies: Any, base: Any = None) -> Callable[[Callable[..., None]], Any]:
    """A hypothesis property over ``strategies`` as a test run in both tiers (:func:`examples`):
    ``base``'s settings with ``quick`` or ``full`` examples. The decorated function is the
    property itself (its arguments are the drawn values), named as the test."""
    from hypothesis import given, settings

    def wrap(prop: Callable[..., None]) -> Any:
        @pytest.mark.parametrize("count", examples(full, quick))
        def test(count: int) -> None:
            settings(base, max_examples=count)(given(*strategies)(prop))()

        test.__name__, test.__qualname__, test.__doc__ = prop.__name__, prop.__qualname__, prop.__doc__
        return test

    return wrap
