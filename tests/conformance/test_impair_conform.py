"""``--impair SPEC`` on ``mcp-conform``, ``mcp-node`` and ``mcp-fuzz`` (issue 22 item 3): one
syntax, one parser; the runner never fails a case the impairment spoiled, and a faulty node
fails the same rule through a bad link as on a clean one.

End to end on real sockets: one seed of the reference node and one faulty node through the
link (2 runs, 9 before issue 38's cut); the other seeds and the clean against impaired pairs
run on virtual time in tests/sim/test_mutants_sim.py (``IMPAIR``: the same spec and seeds, the
same checks), the faulty node's clean run in test_mutants."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from types import SimpleNamespace

import pytest

from mcp_conform.fuzz.oracles import Input, judge_exchange
from mcp_conform.harness.impair import parse_impairment
from mcp_conform.spec.codec import Action, Message, encode

from .runner_helpers import FAST, ROOT, run_conform, sample_node_command

SPEC = "loss=0.1,dup=0.05,reorder=0.1"
BAD = ("loss=2", "--impair: loss=2 is not a probability 0..1")


def _conform(argv):
    from mcp_conform.conformance.cli import main
    return main(argv)


def _node(argv):
    from mcp_conform.reference_impl.cli import main
    return main(argv)


def _fuzz(argv):
    from mcp_conform.fuzz.cli import main
    return main(argv)


@pytest.mark.parametrize("prog,main,argv", [
    ("mcp-conform", _conform, []),
    ("mcp-node", _node, ["drone", "--id", "1"]),
    ("mcp-fuzz", _fuzz, ["--max-cases", "1"]),
])
@pytest.mark.parametrize("bad", [BAD, ("loss=0.1,bogus=1", "--impair: unknown key 'bogus'"),
                                 ("delay", "--impair: 'delay' is not KEY=VALUE")])
def test_a_bad_spec_is_the_same_one_line_exit_2_on_every_cli(prog, main, argv, bad, capsys):
    spec, message = bad
    assert main([*argv, "--impair", spec]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"{prog}: error: {message}") and "\n" not in err, err


def test_a_good_spec_is_parsed_the_same_by_conform_and_fuzz():
    from mcp_conform.conformance.cli import _values, build_parser
    from mcp_conform.conformance.options import make_config
    from mcp_conform.fuzz.cli import build_parser as fuzz_parser
    from mcp_conform.fuzz.cli import make_config as fuzz_config

    text = f"{SPEC},delay=0-50ms,seed=7"
    want = parse_impairment(text)
    cfg = make_config(_values(build_parser().parse_args(["--impair", text])), lambda n: "--" + n)
    fcfg = fuzz_config(fuzz_parser().parse_args(["--impair", text]))
    assert cfg.impair == want == fcfg.impair
    assert cfg.parameters()["impair"] == want.text()  # the report says what the link was
    assert fcfg.run_config().impair == want  # the fuzzer's driver goes through it


def test_the_fuzzer_never_judges_an_exchange_the_impairment_touched():
    """An unACKed unicast input with the probe behind it ACKed is MCP-ACK-1 on a clean link;
    when the link touched the exchange (the ACK may be what it dropped) it is not judged."""
    inp = Input.of(encode(Message(1, 0x20, 77, Action.WP_OFF, None)))
    driver = SimpleNamespace(received=lambda mark: [], our_id=0, link=None, mark=lambda: 0,
                             send_raw=lambda data: SimpleNamespace(seq=77, src=0x20),
                             ack_for=lambda sent: (lambda d: True), wait_for=lambda *a: None,
                             exchange=lambda first, **kw: SimpleNamespace(acked=False, copies=[first] * 4))
    probe = SimpleNamespace(acked=True, sent=SimpleNamespace(seq=1), copies=1)

    def target(spoiled):
        return SimpleNamespace(driver=driver, node_id=1, broadcast_id=0xFFFF, rto=0.01, ack_window=0.01,
                               observations={}, fate=lambda: {"alive": True},
                               impairment_spoiled=lambda: spoiled)

    assert [f.rule for f in judge_exchange([inp], target([]), 0, probe)] == ["MCP-ACK-1"]
    assert judge_exchange([inp], target(["ACK seq 77 1->32 (received) drop:loss"]), 0, probe) == []


def test_mcp_node_drone_on_a_bad_link_sends_each_datagram_twice():
    """``mcp-node drone --impair dup=1``: the node's own socket duplicates what it sends
    (its Mission_Ready arrives twice, the same bytes); without it, once."""
    def copies(*extra: str) -> list[bytes]:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx, \
                socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            rx.bind(("127.0.0.1", 0))
            probe.bind(("127.0.0.1", 0))
            port = probe.getsockname()[1]
            probe.close()
            rx.settimeout(20)
            env = dict(os.environ, PYTHONPATH=str(ROOT))
            proc = subprocess.Popen([sys.executable, "-m", "mcp_conform.reference_impl", "drone", "--id", "1", "-q",
                                     "--bind", f"127.0.0.1:{port}", "--send-to", f"127.0.0.1:{rx.getsockname()[1]}",
                                     *extra], env=env, cwd=ROOT, stdout=subprocess.DEVNULL,
                                    stderr=subprocess.DEVNULL)
            try:
                got = [rx.recvfrom(65535)[0]]
                end = time.monotonic() + 1.0  # well within its 5 s retransmission timeout
                rx.settimeout(0.1)
                while time.monotonic() < end:
                    try:
                        got.append(rx.recvfrom(65535)[0])
                    except TimeoutError:
                        pass
            finally:
                proc.terminate()
                proc.wait(10)
        return got

    twice = copies("--impair", "dup=1,seed=3")
    assert len(twice) == 2 and twice[0] == twice[1], twice
    assert len(copies()) == 1


# ---------------------------------------------------------------------- end to end
@pytest.mark.slow
@pytest.mark.parametrize("seed", [1])
def test_the_reference_node_through_a_bad_link_has_no_failure(seed):
    """Seed 1 on real sockets and timers (the runner's defaults: 13-19 s a run); seeds 2-5 on
    virtual time: tests/sim/test_mutants_sim.py::test_the_reference_drone_through_the_runners_
    impaired_link_has_no_failure, the same checks."""
    res = run_conform("--impair", f"{SPEC},seed={seed}")
    assert res.rc == 0, res.explain()
    assert not res.cases_with("failed", "warned", "error"), res.explain()
    assert res.report["monitor"]["complete"] is False  # the monitor is told the link is lossy
    assert res.report["parameters"]["impair"] == f"{SPEC},seed={seed}"


@pytest.mark.slow
@pytest.mark.parametrize("fault,rule", [("ack-broadcast", "MCP-ACK-4")])
def test_a_faulty_node_fails_the_same_rule_through_a_bad_link(fault, rule):
    """The spawned sample node through the runner's impaired link on real sockets. Its clean run
    is test_mutants' (the same node and options: ``test_mutant_is_caught_with_its_rule[ack-
    broadcast]`` asserts MCP-ACK-4 failed and nothing else); ``no-dup-discard`` clean and through
    the link, and ``ack-broadcast`` again, on virtual time: tests/sim/test_mutants_sim.py::
    test_a_mutant_fails_the_same_rule_through_the_runners_impaired_link."""
    from .test_mutants import REAL_MUTANTS

    assert (fault, rule) in REAL_MUTANTS  # its clean run is made there
    bad = run_conform("--spawn", sample_node_command("--fault", fault), "--mavlink", *FAST,
                      "--impair", f"{SPEC},seed=11")
    assert bad.rules_with("failed") == {rule: "failed"}, bad.explain()
    assert not bad.rules_with("warned"), bad.explain()
