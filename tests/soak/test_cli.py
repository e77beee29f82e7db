"""``mcp-soak``'s command line (issue 22 item 4): bad options are one line and exit 2, the
reproducing command names the mission's seed and challenge, p50/p99 (what a drone must get:
tests/soak/test_mission_judge.py)."""

from __future__ import annotations

import shlex

import pytest

from mcp_conform.soak.cli import build_parser, main, percentile, reproduce
from mcp_conform.soak.mission import MissionResult


@pytest.mark.parametrize("argv, words", [
    (["--impair", "loss=2"], "not a probability"),
    (["--impair", "bogus=1"], "unknown key"),
    (["--missions", "0"], "--missions"),
    (["--drone", "my_drone --id {nope}"], "unknown placeholder {nope}"),
    (["--waypoints", "/no/such/file"], "no such file"),
    (["--rto", "0"], "must be > 0"),
])
def test_a_bad_option_is_one_line_and_exit_2(argv, words, capsys, tmp_path):
    assert main([*argv, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("mcp-soak: error:") and words in err and err.count("\n") == 1


def test_bad_ids_are_argparse_errors_exit_2(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--drones", "1,1"])
    assert exc.value.code == 2
    assert "--drones" in capsys.readouterr().err


def test_the_reproducing_command_replays_one_mission_by_its_seed():
    ns = build_parser().parse_args(["--missions", "50", "--seed", "100", "--impair", "loss=0.3,dup=0.1,seed=4",
                                    "--drone", "my_drone --id {id}", "--rto", "0.5"])
    r = MissionResult(index=7, seed=107, challenge=2, impair="loss=0.3,dup=0.1,seed=107")
    words = shlex.split(reproduce(ns, r))
    assert words[0] == "mcp-soak"
    opts = dict(zip(words[1::2], words[2::2], strict=False))
    assert opts["--missions"] == "1" and opts["--seed"] == "107" and opts["--challenges"] == "2"
    assert opts["--impair"] == "loss=0.3,dup=0.1" and opts["--drone"] == "my_drone --id {id}"
    assert opts["--rto"] == "0.5"


def test_percentiles():
    assert percentile([], 50) is None
    assert percentile([3.0, 1.0, 2.0], 50) == 2.0
    assert percentile([float(i) for i in range(1, 101)], 99) == 99.0

