"""The spawned node's run delay never goes down (``harness.run_delay``, D-7): a thread or a
descendant process that ended keeps the count it had when last read. Summed over the live
threads only, the reading fell when a thread ended (a worker that had waited 0.70 s on a loaded
host ended and the reading fell to 0.01 s), so a node that sends from a thread of its own lost
the waits that made its copies late, and the judges, which take the growth between readings,
excused nothing of them."""

from __future__ import annotations

import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mcp_conform.harness.run_delay import run_delay_ns


def _task(root: Path, pid: int, tid: int, delay: int, children: str = "", started: int = 1000) -> None:
    d = root / str(pid) / "task" / str(tid)
    d.mkdir(parents=True, exist_ok=True)
    (d / "schedstat").write_text(f"123456 {delay} 7\n")
    (d / "children").write_text(children)
    # /proc/<pid>/stat: field 22 is the start time (the comm may hold spaces and parentheses)
    (root / str(pid) / "stat").write_text(f"{pid} (a (node)) S " + " ".join(["0"] * 18) + f" {started} 0\n")


def test_a_thread_that_ended_keeps_its_count(tmp_path):
    _task(tmp_path, 10, 10, 100)
    _task(tmp_path, 10, 11, 700)  # the worker that sent, late
    assert run_delay_ns(10, str(tmp_path)) == 800
    shutil.rmtree(tmp_path / "10" / "task" / "11")  # it ended
    _task(tmp_path, 10, 10, 150)
    assert run_delay_ns(10, str(tmp_path)) == 850  # not 150


def test_a_descendant_that_ended_keeps_its_count(tmp_path):
    _task(tmp_path, 20, 20, 5, "21")  # a shell
    _task(tmp_path, 21, 21, 300)  # the node
    assert run_delay_ns(20, str(tmp_path)) == 305
    shutil.rmtree(tmp_path / "21")
    _task(tmp_path, 20, 20, 5, "")
    assert run_delay_ns(20, str(tmp_path)) == 305


def test_a_new_thread_under_an_old_id_adds_to_the_old_ones_count(tmp_path):
    _task(tmp_path, 30, 30, 10)
    _task(tmp_path, 30, 31, 400)
    assert run_delay_ns(30, str(tmp_path)) == 410
    _task(tmp_path, 30, 31, 20)  # thread 31 ended, a new one took its ID
    assert run_delay_ns(30, str(tmp_path)) == 430


def test_a_process_gone_is_forgotten_and_a_new_one_under_its_id_starts_afresh(tmp_path):
    _task(tmp_path, 40, 40, 900)
    assert run_delay_ns(40, str(tmp_path)) == 900
    shutil.rmtree(tmp_path / "40")
    assert run_delay_ns(40, str(tmp_path)) is None
    _task(tmp_path, 40, 40, 3, started=2000)
    assert run_delay_ns(40, str(tmp_path)) == 3
    _task(tmp_path, 40, 40, 4, started=3000)  # another process again, never seen gone
    assert run_delay_ns(40, str(tmp_path)) == 4


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc/<pid>/task/*/schedstat is Linux's")
def test_a_real_worker_thread_ending_does_not_lower_the_reading():
    code = ("import threading, time\n"
            "def spin():\n"
            "    end = time.monotonic() + 0.3\n"
            "    while time.monotonic() < end: pass\n"
            "t = threading.Thread(target=spin); t.start(); t.join()\n"
            "time.sleep(5)\n")
    p = subprocess.Popen([sys.executable, "-c", code])
    try:
        readings = []
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:  # bounded: 3 s of readings, across the worker's end
            rd = run_delay_ns(p.pid)
            assert rd is not None
            readings.append(rd)
            time.sleep(0.02)
        assert readings == sorted(readings), readings
    finally:
        p.kill()
        p.wait()
