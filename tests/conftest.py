"""The test run's order: the longest slow tests first, a few at the head of each worker's share.

A long test that starts last makes the whole run as long as itself on top of everything before
it. These are the tests that wait on protocol timers at the description's real timings (5 s) or
run a fuzz campaign until it finds its fault: started first, they overlap with everything else.
Under ``--dist worksteal`` (CI) each worker is first handed a contiguous share of the list and
works it from the front, idle workers stealing the back half of the longest share: with the
long tests simply first, worker 0's share held all of them, one after another (the last began
at 321 s of 356). So they are dealt round-robin to the heads of the shares (``dealt``). Nothing
is skipped or shortened by this; it only decides what runs first and where.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

import pytest

#: Substrings of node IDs of the longest tests, longest first: the slow run's tests of 22 s and
#: more (--durations=0 of two runs of ``-n 10 -m slow`` on the 2-core host, their mean; most
#: wait on protocol timers, the description's 5 s timeout, a fixed-length fuzz campaign).
LONG_FIRST = (
    # CI at 14 workers (538 s, 2026-11-29): the CPU-heavy ones slow most under contention
    "test_dist.py::test_the_sdist_tests_itself_and_the_wheel_runs_outside_the_checkout",  # 129 s (18 s alone)
    "test_reader.py::test_mcap_cut_at_every_byte[1]",  # 106 s (9 s alone)
    "test_hostile_files.py::test_check_of_a_million_violating_datagrams_finishes_under_the_limit",  # 92 s
    "test_faults.py::test_spawn_node_killed_mid_run_at_the_descriptions_timings",  # 71 s
    "test_docs.py::test_docs_site_builds_strict",  # 59 s in the slow run (moved from the quick one)
    # MAVLink's whole suites on real processes (session 29's profile, -n 12, 2 cores): the vehicle
    # role's runs stay whole; the gcs role's run as three parts at once (~30-45 s each now)
    "test_conform_mavlink.py::test_a_faulty_vehicle_through_the_real_proxy[abandoned-stays-busy]",  # 51 s
    "test_mavsdk_vehicle.py::test_mavsdk_server_fails_the_unknown_command_and_the_deprecated_items[tcp]",  # 51 s
    "test_mavsdk_vehicle.py::test_mavsdk_server_fails_the_unknown_command_and_the_deprecated_items[udp]",  # 50 s
    "test_conform_mavlink.py::test_reference_vehicle_passes_every_case[tcp]",  # 48 s, shared by two more
    "test_conform_gcs.py::test_reference_gcs_passes_every_case",  # 45 s (84 s whole)
    "test_conform_mavlink.py::test_reference_vehicle_passes_every_case[udpout]",  # 44 s
    "test_conform_mavlink.py::test_a_faulty_vehicle_through_the_real_proxy[double-ack]",  # 43 s
    "test_conform_mavlink.py::test_reference_vehicle_passes_every_case[udp]",  # 42 s
    "test_mavlink_fuzz.py::test_a_fragile_vehicle_is_found_confirmed_and_replays[mission-seq-hang]",  # 42 s
    "test_mavlink_fuzz.py::test_a_fragile_vehicle_is_found_confirmed_and_replays[slow-heartbeat]",  # 38 s
    "test_conform_gcs.py::test_mavproxy_wp_load",  # 31 s (73 s whole)
    "test_seed001_gcs.py::test_seed_programs_through_the_gcs_suite[mission_takeoff -b-udpout]",  # 30 s (91 s whole)
    "test_conform_gcs.py::test_real_ground_stations[dronekit]",  # 28 s (61 s whole)
    "test_dissector.py::test_tshark_on_the_golden_captures[drone-suite]",  # 60 s
    "test_oracle_observation.py::test_a_correct_node_with_a_small_receive_buffer_has_no_finding_in_a_campaign",  # 61 s
    "test_conform_nsqd.py::test_each_fault_fails_its_own_rule_and_no_other[switch-fallthrough]",  # 56 s
    "test_manager_role.py::test_no_false_alarm_with_the_descriptions_5_s_timeout",  # 53 s
    "test_stateful_finds.py::test_a_sequence_fault_is_found_and_confirmed_at_the_default_settings[ack-first-copy-only-1]",  # 53 s
    "test_faults.py::test_attach_node_killed_mid_run_at_the_descriptions_timings",  # 51 s
    "test_one_judge.py::test_check_of_a_merged_xdist_manager_capture_gives_each_workers_live_verdicts[no-ready-ack]",  # 49 s
    "test_golden_runs.py::test_pairs_of_whole_suite_runs_are_the_same",  # 48 s
    "test_nsqd_stateful.py::test_no_false_alarm_on_a_correct_backend[reference]",  # 45 s
    "test_nsqd_stateful.py::test_no_false_alarm_on_a_correct_backend[c]",  # 45 s
    "test_stateful_finds.py::test_a_sequence_fault_is_found_and_confirmed_at_the_default_settings[ack-first-copy-only-2]",  # 45 s
    "test_nsqd_fuzz.py::test_each_class_is_found_confirmed_and_replays[unbounded-gpx-alloc]",  # 44 s
    "test_apps.py::test_dronekit_app_conforms_at_the_descriptions_timeout",  # 43 s
    "test_mutants.py::test_no_false_alarm_with_the_descriptions_5_s_timeout",  # 42 s
    "test_nsqd_recover_mode.py::test_a_death_after_non_fatal_reports_is_confirmed_by_its_cause",  # 41 s
    "test_stateful_finds.py::test_a_sequence_fault_is_found_and_confirmed_at_the_default_settings[seq-no-wrap-2]",  # 39 s
    "test_conform_nsqd.py::test_each_fault_fails_its_own_rule_and_no_other[update-stops]",  # 38 s
    "test_conform_nsqd.py::test_correct_c_backend_passes",  # 38 s
    "test_golden_runs.py::test_pairs_of_runs_of_the_same_cases_are_the_same",  # 37 s
    "test_stateful_finds.py::test_a_sequence_fault_is_found_and_confirmed_at_the_default_settings[seq-no-wrap-1]",  # 37 s
    "test_faulty_nodes.py::test_seeded_campaign_finds_the_fault_and_its_reproducer_replays[hang-on-big]",  # 35 s
    "test_nsqd_fuzz.py::test_each_class_is_found_confirmed_and_replays[early-return-keeps-size]",  # 32 s
    "test_conform_nsqd.py::test_each_fault_fails_its_own_rule_and_no_other[wrong-stop-test-state]",  # 31 s
    "test_nsqd_fuzz.py::test_each_class_is_found_confirmed_and_replays[unknown-id-no-skip]",  # 31 s
    "test_faulty_nodes.py::test_seeded_campaign_finds_the_fault_and_its_reproducer_replays[seq-no-wrap]",  # 30 s
    "test_nsqd_progress_jobs.py::test_jobs_share_the_example_database",  # 29 s
    "test_conform_nsqd.py::test_each_fault_fails_its_own_rule_and_no_other[no-close-on-bad-length]",  # 27 s
    "test_one_judge.py::test_check_of_a_merged_xdist_manager_capture_gives_each_workers_live_verdicts[wrong-seq-ack]",  # 27 s
    "test_nsqd_one_judge.py::test_live_and_offline_verdicts_agree[None]",  # 26 s
    "test_capture_tools_e2e.py::test_check_on_tcpdump_and_dumpcap_captures_of_a_real_mission",  # 26 s
    "test_hostile_files.py::test_replay_to_a_dead_port_is_a_setup_error",  # 26 s
    "test_nsqd_fuzz.py::test_each_class_is_found_confirmed_and_replays[crash-on-negative-string]",  # 26 s
    "test_impair_conform.py::test_a_faulty_node_fails_the_same_rule_through_a_bad_link[ack-broadcast-MCP-ACK-4]",  # 25 s
    "test_stateful_finds.py::test_no_finding_on_the_correct_node_at_the_default_settings",  # 25 s
    "test_blame.py::test_a_backend_that_misbehaves_whatever_it_is_sent_is_its_own_finding[slow-NSQD-MSG-1]",  # 25 s
    "test_one_judge.py::test_check_of_a_merged_xdist_manager_capture_gives_each_workers_live_verdicts[le-count]",  # 25 s
    "test_one_judge.py::test_check_of_a_merged_xdist_capture_gives_each_workers_live_verdicts[reference-node]",  # 24 s
    "test_nsqd_one_judge.py::test_live_and_offline_verdicts_agree[update-state-little-endian]",  # 24 s
    "test_conform_nsqd.py::test_reference_backend_passes_every_rule",  # 24 s
    "test_nsqd_fuzz.py::test_each_class_is_found_confirmed_and_replays[crash-on-bad-number]",  # 24 s
    "test_soak_faults.py::test_the_correct_sample_nodes_complete_the_same_missions[loss=0.2,dup=0.7,reorder=0.5,delay=0-150ms-1-1,2,3,4,5]",  # 24 s
    "test_faulty_nodes.py::test_seeded_campaign_finds_the_fault_and_its_reproducer_replays[ack-bad-preamble]",  # 24 s
    "test_xdist.py::test_spawn_mode_under_xdist_leaves_one_report_of_each_kind",  # 23 s
    "test_manager_role.py::test_a_manager_that_sends_nothing_never_answered",  # 23 s
    # the quick run's longest (they wait), first there
    "test_schedule.py::test_a_scheduled_run_watches_its_windows_together_and_serial_one_after_another",
    "test_forkserver.py::test_an_environment_read_at_import_gets_a_server_imported_with_it",
)


def _rank(item: pytest.Item) -> int:
    for i, part in enumerate(LONG_FIRST):
        if part in item.nodeid:
            return i
    return len(LONG_FIRST)


#: Tests that mostly wait (the Nsqd matrices: ~700 s of wall for ~40 CPU s): spread through every
#: share, not left together at the end, where they ran on an idle CPU for the last ~30 s.
WAITERS = ("tests/nsqd/test_conform_nsqd.py::", "tests/fuzz/test_nsqd_fuzz.py::", "tests/fuzz/test_nsqd_stateful.py::")


def dealt(items: list, long: int, workers: int, waits: Callable[[Any], bool] = lambda it: False) -> list:
    """``items`` (their first ``long`` the long tests, longest first) reordered so that worksteal's
    first hand-out (share ``i`` of ``workers``: ``remaining // (workers - i)`` items from the
    front) gives each share long tests ``i``, ``i + workers``, ... at its head, then the rest in
    order with the tests that ``waits`` dealt round-robin and spaced evenly among them."""
    if workers < 2 or len(items) < 2 * workers:
        return items
    longs = items[:long]
    waiters = [it for it in items[long:] if waits(it)]
    rest = iter([it for it in items[long:] if not waits(it)])
    out: list = []
    left = len(items)
    for i in range(workers):
        size = left // (workers - i)
        left -= size
        head, mine = longs[i::workers][:size], waiters[i::workers]
        others = [x for x in (next(rest, None) for _ in range(size - len(head) - len(mine))) if x is not None]
        step, spread, body = max(1, len(others) // max(1, len(mine))), iter(mine), []
        for k, x in enumerate(others):  # a waiter before every step-th of the others
            if k % step == 0:
                body += [w for w in [next(spread, None)] if w is not None]
            body.append(x)
        out += head + body + list(spread)
    return out + list(rest)


#: Tests bound by CPU alone, on virtual time or pure computation: no protocol timer, no real
#: socket wait, so load changes how long they take and nothing else (the simulator's runs, a
#: million-datagram check, a capture cut at every byte). Marked ``cpu``: the README's quick run
#: (``-m "not slow and not cpu"``) leaves them out, and CI runs them niced beside the slow
#: tests, on the CPU those leave idle while they wait on timers (``.ci/run``). Node-ID prefixes.
CPU_BOUND = (
    "tests/sim/",
    "tests/traceio/test_hostile_files.py::test_check_of_a_million_violating_datagrams_finishes_under_the_limit",
    "tests/traceio/test_reader.py::test_mcap_cut_at_every_byte",
)


def pytest_itemcollected(item: pytest.Item) -> None:
    """``cpu`` on the tests of ``CPU_BOUND`` (before ``-m`` selects: collection time)."""
    if item.nodeid.startswith(CPU_BOUND):
        item.add_marker(pytest.mark.cpu)


@pytest.hookimpl(trylast=True)  # after -m's deselection: the shares are of the tests that run
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    items.sort(key=_rank)  # stable: everything else keeps its order
    long = sum(1 for it in items if _rank(it) < len(LONG_FIRST))
    items[:] = dealt(items, long, int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "0")),
                     lambda it: it.nodeid.startswith(WAITERS))


def tier(item: pytest.Item) -> str:
    """The CI tier a test runs in (``.ci/run``): ``cpu``, ``slow`` or ``quick``."""
    return next((m for m in ("cpu", "slow") if item.get_closest_marker(m) is not None), "quick")


def pytest_collection_finish(session: pytest.Session) -> None:
    """``MCP_TEST_TIERS=FILE`` (CI's one collection before the tiers start, ``.ci/run``): each
    test file's tiers written to FILE, "tier<TAB>path" a line, so that each tier's workers
    collect only the files that hold its tests. Every xdist worker collects what it is given,
    all at once as the tier starts: measured on a loaded host (session 32), the whole tree 4.2
    CPU s, the slow tests' 81 files 2.6, the CPU-bound tests' 22 files 1.7; the slow tier's 12
    workers and the CPU-bound tier's 2 each paid the difference. The tiers' ``-m``
    still selects: a file list that held more would change nothing but that cost."""
    out = os.environ.get("MCP_TEST_TIERS")
    if not out:
        return
    lines = sorted({f"{tier(it)}\t{it.nodeid.split('::', 1)[0]}" for it in session.items})
    with open(out, "w") as f:
        f.write("".join(line + "\n" for line in lines))


def pytest_configure(config: pytest.Config) -> None:
    """On a fresh clone each of ``-n N`` workers compiles the same modules and rewrites the same
    test files at once, N times the work of one (the quick tests: 68 s cold, 57 s warm). The
    controller does it once first: the packages and the tests' helpers compiled as ``import``
    would (``compileall``), the test files rewritten as pytest's assertion rewriter would, with
    its own functions (a pytest without them: skipped; the workers then do it as before)."""
    import sys

    if hasattr(config, "workerinput") or not config.getoption("numprocesses", None) or sys.dont_write_bytecode:
        return
    import compileall
    from pathlib import Path

    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib  # type: ignore[no-redef]

    root = Path(__file__).resolve().parents[1]
    packages = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["importlinter"]["root_packages"]
    for name in (*packages, "tests"):
        compileall.compile_dir(str(root / name), quiet=2)
    try:
        from _pytest.assertion import rewrite

        state = config.stash[rewrite.assertstate_key]
        for fn in [*root.glob("tests/**/test_*.py"), *root.glob("tests/**/conftest.py")]:
            pyc = rewrite.get_cache_dir(fn) / (fn.name[:-3] + rewrite.PYC_TAIL)
            if rewrite._read_pyc(fn, pyc) is None and rewrite.try_makedirs(pyc.parent):
                source_hash, co = rewrite._rewrite_test(fn, config)
                rewrite._write_pyc(state, co, source_hash, pyc)
    except (ImportError, AttributeError, KeyError, TypeError):
        pass


#: ``MCP_TEST_CPU=FILE``: each test's CPU seconds (the worker's and its waited-for children's,
#: user + system) appended to FILE as "seconds<TAB>nodeid<TAB>worker<TAB>start<TAB>end" (start
#: and end: wall-clock time.time(), setup to teardown) -- where CI's time goes on 2 cores, and
#: when each worker was busy (the run's tail: a worker idle while another still runs). The
#: runner's forkserver (tests/forkserver.py) is no child of the worker: its runs' CPU is not in it.
_CPU_FILE = __import__("os").environ.get("MCP_TEST_CPU")


def _cpu() -> float:
    import resource

    s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None):  # type: ignore[no-untyped-def]
    if _CPU_FILE is None:
        yield
        return
    import time

    before, start = _cpu(), time.time()
    yield
    worker = os.environ.get("PYTEST_XDIST_WORKER", "-")
    with open(_CPU_FILE, "a", encoding="utf-8") as f:
        f.write(f"{_cpu() - before:.3f}\t{item.nodeid}\t{worker}\t{start:.3f}\t{time.time():.3f}\n")
