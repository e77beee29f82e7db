"""A signal landing in pytest's own start-up (its argument parsing, which a KeyboardInterrupt
there left half-done: ``AttributeError: ... 'save_required'``, a traceback, exit -2 in a
loaded CI run) waits until the runner's plugin is configured: ``hold`` / ``release``."""

from __future__ import annotations

import os
import signal

import pytest

from mcp_conform.harness.interrupts import Interrupts


def test_a_signal_while_held_stops_the_run_at_release_not_before():
    it = Interrupts()
    assert it.install()
    try:
        it.hold()
        os.kill(os.getpid(), signal.SIGINT)  # delivered at once, in this (the main) thread
        assert it.interrupted  # seen, not raised
        with pytest.raises(KeyboardInterrupt, match="SIGINT"):
            it.release()
        it.release()  # once only
    finally:
        it.restore()


def test_release_after_the_run_stopped_raising_raises_nothing():
    it = Interrupts()
    assert it.install()
    try:
        it.hold()
        os.kill(os.getpid(), signal.SIGTERM)
        it.stop_raising()
        it.release()  # pytest ended before the plugin released it: the report says interrupted
        assert it.interrupted and it.reason() == "interrupted by SIGTERM"
    finally:
        it.restore()
