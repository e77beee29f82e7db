"""What an oracle reports (:class:`Flaw`) and what it judges (:class:`Input`): shared by the
reply and liveness oracles (``fuzz.oracles``) and the vehicle's (``fuzz.delivery``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import Action, DecodeError, Message, decode

__all__ = ["Flaw", "Input", "rule_level"]


def rule_level(rule: str) -> str:
    return SPEC.rule(rule).level if rule in SPEC.rules_by_id else "MUST"


@dataclass(frozen=True)
class Flaw:
    """One thing the node did wrong: the rule, expected vs actual, and the input to blame
    (``culprit``: index into the inputs judged, None when it is the whole sequence)."""

    rule: str
    expected: str
    actual: str
    culprit: int | None = None
    evidence: tuple[str, ...] = ()
    source: str = "replies"  # replies | liveness | process | vehicle | monitor
    datagram: bytes | None = None  # the culprit's bytes, where the index alone is not enough

    @property
    def level(self) -> str:
        return rule_level(self.rule)


@dataclass(frozen=True)
class Input:
    """One datagram the fuzzer sent, decoded once; ``observed`` is what the oracles learnt of
    it (``acked``: the node answered it, so it reached the node; ``resent``: copies the ACK-1
    observation sent), read by the ledger that recorded the same Input."""

    data: bytes
    header: tuple[int, int, int, int] | None  # (dst, src, seq, action), whatever the preamble
    msg: Message | None
    error: DecodeError | None
    observed: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)

    @property
    def received(self) -> bool:
        """The node answered this datagram (or a copy of it): it reached the node."""
        return bool(self.observed.get("acked"))

    @classmethod
    def of(cls, data: bytes) -> Input:
        from mcp_conform.harness.driver import read_header

        try:
            return cls(data, read_header(data), decode(data), None)
        except DecodeError as exc:
            return cls(data, read_header(data), None, exc)

    def describe(self) -> str:
        if self.msg is not None:
            m = self.msg
            return f"{Action(m.action).name} dst={m.dst} src={m.src} seq={m.seq} ({len(self.data)} B)"
        if self.header is not None:
            dst, src, seq, action = self.header
            return (f"malformed action={action} dst={dst} src={src} seq={seq} ({len(self.data)} B): "
                    f"{self.error}")
        return f"malformed {len(self.data)} B: {self.error}"
