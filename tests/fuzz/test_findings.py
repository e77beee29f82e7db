"""One ``Finding`` and one findings store for every protocol (issue 37): finding.json of MCP
and Nsqd alike is one document, read back by one reader; a file written before the merge
still loads; the store groups, counts and writes each protocol's own files."""

from __future__ import annotations

import json

import pytest

from mcp_conform.fuzz.findings import FindingStore, read_finding
from mcp_conform.fuzz.nsqd_campaign import nsqd_finding
from mcp_conform.fuzz.nsqd_mutators import Case, Write
from mcp_conform.fuzz.nsqd_oracles import Signature
from mcp_conform.fuzz.nsqd_repro import write_finding_files

#: finding.json as the Nsqd campaign wrote it before issue 37
OLD_NSQD = {"protocol": "nsqd", "oracle": "crash", "kind": "SIGSEGV", "access": "", "frames": ["f"],
            "rule": "NSQD-ROB-1", "level": "MUST", "description": "crash: SIGSEGV in f [NSQD-ROB-1]",
            "detail": "died", "note": "length-lie", "replays": "3 of 3", "probe": False,
            "writes": [{"hex": "00ff", "end": ""}], "expect": [], "or_error": False, "no_input": False}
#: finding.json as the MCP campaign wrote it before issue 37
OLD_MCP = {"rule": "MCP-ACK-1", "expected": "an ACK", "actual": "none", "datagrams": ["0102"],
           "shape": "one datagram", "engine": "stateless", "seed": 7, "pace": "batch", "level": "MUST",
           "evidence": [], "worker": 0, "occurrences": 2, "program": None, "scenario": None, "source": "",
           "target": {}, "schema_version": 1, "rule_text": "x"}


@pytest.mark.parametrize("doc", [OLD_NSQD, OLD_MCP], ids=["nsqd", "mcp"])
def test_a_finding_written_before_the_merge_still_loads(tmp_path, doc):
    (tmp_path / "finding.json").write_text(json.dumps(doc))
    f = read_finding(tmp_path)
    assert f.rule == doc["rule"] and f.protocol == doc.get("protocol", "mcp")
    again = f.to_json()
    assert {k: again[k] for k in doc if k != "rule_text"} == {k: v for k, v in doc.items() if k != "rule_text"}


def test_one_reader_refuses_another_protocols_finding(tmp_path):
    (tmp_path / "finding.json").write_text(json.dumps(OLD_MCP))
    with pytest.raises(ValueError, match="not a finding of --protocol nsqd"):
        read_finding(tmp_path, "nsqd")


def test_the_store_groups_and_writes_an_nsqd_finding_as_an_mcp_one(tmp_path):
    sig = Signature("crash", "SIGSEGV", ("f",), "NSQD-ROB-1", "READ")
    case = Case("length-lie", (Write(b"\x00\xff"),))
    store = FindingStore(tmp_path, ["--protocol", "nsqd"], write_finding_files)
    d = store.add(nsqd_finding(sig, [case], "died", "3 of 3", ("ERROR: AddressSanitizer",), note="length-lie"))
    # the same signature but its access: one group, counted (as the campaign's own dedupe)
    assert store.add(nsqd_finding(Signature("crash", "SIGSEGV", ("f",), "NSQD-ROB-1", "WRITE"), [case], "died",
                                  "3 of 3")) is None
    store.rewrite()
    assert d is not None and len(store) == 1
    doc = json.loads((d / "finding.json").read_text())
    assert doc["occurrences"] == 2 and doc["actual"] == doc["detail"] == "died" and doc["writes"][0]["hex"] == "00ff"
    assert doc["protocol"] == "nsqd" and doc["rule_text"] and doc["evidence"] == ["ERROR: AddressSanitizer"]
    assert (d / "input.hex").read_text() == "00 ff\n" and "--protocol nsqd" in (d / "replay.txt").read_text()
    assert read_finding(d, "nsqd").signature is None and read_finding(d / "repro.mcap", "nsqd").rule == "NSQD-ROB-1"


def test_every_protocol_names_the_campaign_mcp_fuzz_runs():
    """``mcp-fuzz`` reaches each protocol's campaign through its profile (``fuzz_campaign``):
    one command line, no branch on a protocol's name (``fuzz.plugin.FuzzCampaign``)."""
    from mcp_conform.fuzz.plugin import FuzzCampaign
    from mcp_conform.spec.profiles import PROFILES, resolve

    wanted = {n for n in vars(FuzzCampaign) if not n.startswith("_")} | set(FuzzCampaign.__annotations__)
    for prof in (p for p in PROFILES.values() if p.fuzz_campaign is not None):  # None: none yet (mavlink)
        cls = resolve(prof.fuzz_campaign)
        assert wanted - {"store"} <= set(dir(cls)), (prof.name, wanted - set(dir(cls)))
        assert all(opt.startswith("--") for opt in cls.REFUSED)
