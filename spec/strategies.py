"""Hypothesis strategies and a seeded malformed corpus, derived from ``spec/mcp.yaml``.

- :func:`messages` draws valid :class:`~spec.codec.Message` values per action code, with the
  payload typed as the spec's payload layout says (mission items of 32-bit floats so they
  survive the 37-byte MISSION_ITEM packing, MCP-PAY-4; Mission_Ready's optional ID equal to
  src, D-3; one pymavlink-packed MAVLink v1 or v2 frame for Mav_Passthrough, MCP-PAY-6).
- :func:`datagrams` draws their encoded bytes.
- :func:`malformed_datagrams` draws bytes that :func:`spec.codec.decode` rejects, per kind;
  :data:`MALFORMED_KINDS` maps each kind to the rule its rejection cites.
- :func:`malformed_corpus` (``spec.generators``, re-exported) builds the same kinds from a
  seeded ``random.Random``: a fixed corpus (same seed, same bytes, in any process) for the
  conformance runner, which imports ``spec.generators`` alone and never hypothesis.

Both paths run the same builders (``spec.generators``) through a small chooser interface, so
the corpus is drawn from exactly the strategies' space.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from hypothesis import strategies as st

from mcp_conform.spec.codec import (
    Action,
    Message,
    MissionItem,
    encode,
)
from mcp_conform.spec.generators import (
    _BUILDERS,
    MALFORMED_KINDS,
    WIRE_ACTIONS,
    T,
    _item,
    _message,
    malformed_corpus,
    random_malformed,
    random_mavlink_frame,
    random_message,
)

__all__ = [
    "MALFORMED_KINDS",
    "WIRE_ACTIONS",
    "datagrams",
    "malformed_corpus",
    "malformed_datagrams",
    "messages",
    "mission_items",
    "random_malformed",
    "random_mavlink_frame",
    "random_message",
]


class _HypothesisChooser:
    """Choices drawn by hypothesis (so failures shrink)."""

    def __init__(self, draw: Callable[[st.SearchStrategy[Any]], Any]) -> None:
        self._draw = draw

    def integer(self, lo: int, hi: int) -> int:
        return int(self._draw(st.integers(lo, hi)))

    def choice(self, options: Sequence[T]) -> T:
        return self._draw(st.sampled_from(options))  # type: ignore[no-any-return]

    def float32(self) -> float:
        return float(self._draw(st.floats(width=32, allow_nan=False)))

    def blob(self, lo: int, hi: int) -> bytes:
        return bytes(self._draw(st.binary(min_size=lo, max_size=hi)))


# ---------------------------------------------------------------- public strategies
def mission_items() -> st.SearchStrategy[MissionItem]:
    """Mission items whose floats are float32 (they round-trip through the codec exactly)."""
    return st.composite(lambda draw: _item(_HypothesisChooser(draw)))()


def messages(action: Action | int | None = None) -> st.SearchStrategy[Message]:
    """Valid messages: of ``action`` when given, else of any on-wire action code."""
    act = None if action is None else Action(action)
    if act is not None and act not in WIRE_ACTIONS:
        raise ValueError(f"action {act!r} never goes on the wire (MCP-HDR-3)")
    return st.composite(lambda draw: _message(_HypothesisChooser(draw), act))()


def datagrams(action: Action | int | None = None) -> st.SearchStrategy[bytes]:
    """The encoded bytes of :func:`messages`."""
    return messages(action).map(encode)


def malformed_datagrams(kind: str | None = None) -> st.SearchStrategy[bytes]:
    """Bytes that ``decode`` rejects with ``MALFORMED_KINDS[kind]`` (any kind when None)."""
    if kind is not None and kind not in MALFORMED_KINDS:
        raise ValueError(f"unknown malformed kind {kind!r}; known: {', '.join(MALFORMED_KINDS)}")
    kinds = [kind] if kind is not None else list(MALFORMED_KINDS)

    @st.composite
    def build(draw: Callable[[st.SearchStrategy[Any]], Any]) -> bytes:
        c = _HypothesisChooser(draw)
        k = c.choice(kinds)
        return _BUILDERS[k](c, c.integer(0, 0xFFFF), c.integer(0, 0xFFFF), c.integer(0, 0xFFFF), True)

    return build()


