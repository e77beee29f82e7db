"""The manager suite run on an example Mission Manager built by its test (C++, Go), once a
test session: the JSON report with the run's exit code and output, and the MUST rules it
failed. The managers differ only in their options' spelling (``--bind`` / ``-bind``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from spec import load
from tests.forkserver import run_module
from tests.xdist_once import once

RTO = "0.3"


def run_manager_suite(tmp_path_factory: pytest.TempPathFactory, prefix: str, binary: Path, build: str,
                      challenge: str, node_args: str = "", dash: str = "--") -> dict[str, Any]:
    """The suite's JSON report on ``binary`` (build ``build``) at --rto/--ack-window 0.3,
    ``node_args`` more of the node's options, ``dash`` how its options are spelled."""

    def make(out: Path) -> dict[str, Any]:
        report = out / "r.json"
        o = dash
        spawn = (f"{binary} {o}bind {{target_host}}:{{target_port}} {o}send-to {{broadcast}}:{{listen_port}}"
                 f" {o}drones {{drones}} {o}challenge {{challenge}} {o}waypoints {{waypoints}}"
                 f" {o}obstacles {{obstacles}} {o}rto {RTO} {node_args}")
        proc = run_module("conformance", ["--role", "manager", "--challenge", challenge, "--rto", RTO,
                                          "--ack-window", RTO, "--json", str(report), "--spawn", spawn],
                          timeout=300)
        assert report.exists(), proc.stdout + proc.stderr
        doc: dict[str, Any] = json.loads(report.read_text())
        doc["exit_code"] = proc.returncode
        doc["output"] = proc.stdout + proc.stderr
        return doc

    name = f"{prefix}_{build}_c{challenge}_{node_args.replace(' ', '').replace('-', '')}"
    result: dict[str, Any] = once(tmp_path_factory, name, make)
    return result


def failed_must(doc: dict[str, Any]) -> set[str]:
    """The MUST rules the report says failed."""
    must = {r.id for r in load().rules if r.level == "MUST"}
    return {rule for rule, outcome in doc["rules"].items() if outcome == "failed" and rule in must}
