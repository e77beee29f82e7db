"""spec.strategies: valid messages per action, malformed kinds, and the seeded corpus."""

from __future__ import annotations

import subprocess
import sys

import pytest
from hypothesis import given, settings

from mcp_conform.spec.codec import (
    HEADER_SIZE,
    Action,
    DecodeError,
    Message,
    decode,
    encode,
    peek_header,
)
from mcp_conform.spec.mavframe import parse_frame
from mcp_conform.spec.strategies import (
    MALFORMED_KINDS,
    WIRE_ACTIONS,
    malformed_corpus,
    malformed_datagrams,
    messages,
)

FAST = settings(max_examples=40, deadline=None)


def test_kinds_and_rules() -> None:
    assert MALFORMED_KINDS == {
        "short": "MCP-ROB-1", "bad_preamble": "MCP-ROB-2", "unknown_action": "MCP-ROB-3",
        "wrong_payload_length": "MCP-ROB-4", "count_mismatch": "MCP-ROB-4",
        "bad_mavlink_crc": "MCP-PAY-6"}
    assert [int(a) for a in WIRE_ACTIONS] == list(range(9))


@pytest.mark.parametrize("action", list(WIRE_ACTIONS), ids=lambda a: a.name)
def test_messages_per_action_are_valid(action: Action) -> None:
    @FAST
    @given(messages(action))
    def check(msg: Message) -> None:
        assert msg.action is action
        assert decode(encode(msg)) == msg
        if action == Action.MISSION_READY:
            assert msg.payload in (None, msg.src)  # D-3
        if action == Action.MAV_PASSTHROUGH:
            parse_frame(msg.payload)

    check()


def test_messages_refuses_any() -> None:
    with pytest.raises(ValueError, match="MCP-HDR-3"):
        messages(Action.ANY)
    with pytest.raises(ValueError, match="unknown malformed kind"):
        malformed_datagrams("nonsense")


@FAST
@given(messages(Action.MAV_PASSTHROUGH))
def test_passthrough_frames_are_v1_and_v2(msg: Message) -> None:
    assert msg.payload[0] in (0xFE, 0xFD)


def test_passthrough_draws_both_versions() -> None:
    seen = set()

    @settings(max_examples=60, deadline=None)
    @given(messages(Action.MAV_PASSTHROUGH))
    def collect(msg: Message) -> None:
        seen.add(msg.payload[0])

    collect()
    assert seen == {0xFE, 0xFD}


@pytest.mark.parametrize("kind", sorted(MALFORMED_KINDS))
def test_each_kind_is_rejected_with_its_rule(kind: str) -> None:
    @FAST
    @given(malformed_datagrams(kind))
    def check(data: bytes) -> None:
        with pytest.raises(DecodeError) as info:
            decode(data)
        assert info.value.rule == MALFORMED_KINDS[kind]

    check()


def test_corpus_is_deterministic_and_rejected_with_the_right_rules() -> None:
    corpus = malformed_corpus(seed=42, per_kind=12, dst=3, src=0, first_seq=1000)
    assert corpus == malformed_corpus(seed=42, per_kind=12, dst=3, src=0, first_seq=1000)
    assert corpus != malformed_corpus(seed=43, per_kind=12, dst=3, src=0, first_seq=1000)
    assert len(corpus) == 12 * len(MALFORMED_KINDS)
    assert {k for k, _ in corpus} == set(MALFORMED_KINDS)
    for kind, data in corpus:
        with pytest.raises(DecodeError) as info:
            decode(data)
        assert info.value.rule == MALFORMED_KINDS[kind], (kind, data.hex())


def test_corpus_entries_are_addressed_non_acks_with_distinct_seqs() -> None:
    corpus = malformed_corpus(seed=1, per_kind=10, dst=3, src=0, first_seq=65530)
    seqs = []
    for i, (kind, data) in enumerate(corpus):
        if len(data) < HEADER_SIZE:
            assert kind == "short"
            continue
        dst, src, seq, action = _fields(data)
        assert (dst, src) == (3, 0), kind
        assert action != Action.ACK, kind
        assert seq == (65530 + i) & 0xFFFF
        seqs.append(seq)
    assert len(seqs) == len(set(seqs))


def _fields(data: bytes) -> tuple[int, int, int, int]:
    head = peek_header(data)
    if head is None:  # bad preamble: read the header fields regardless
        return tuple(int.from_bytes(data[i:i + 2], "big") for i in (9, 11, 13, 15))  # type: ignore[return-value]
    return head


def test_corpus_starts_with_edge_cases_and_selects_kinds() -> None:
    corpus = malformed_corpus(seed=0, per_kind=3, kinds=["short", "unknown_action"])
    assert [k for k, _ in corpus] == ["short"] * 3 + ["unknown_action"] * 3
    assert corpus[0][1] == b""
    assert len(corpus[2][1]) == HEADER_SIZE - 1
    assert _fields(corpus[3][1])[3] == 9  # "Any" never goes on the wire (MCP-HDR-3)
    with pytest.raises(ValueError, match="unknown malformed kind"):
        malformed_corpus(seed=0, per_kind=1, kinds=["nope"])


def test_corpus_is_the_same_in_another_process() -> None:
    code = ("import hashlib; from spec.strategies import malformed_corpus; "
            "print(hashlib.sha256(b''.join(d for _, d in malformed_corpus(5, 8))).hexdigest())")
    import hashlib

    here = hashlib.sha256(b"".join(d for _, d in malformed_corpus(5, 8))).hexdigest()
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                         env={"PYTHONHASHSEED": "123", "PATH": ""}, cwd=_root())
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == here


def _root() -> str:
    from pathlib import Path

    return str(Path(__file__).resolve().parents[2])
