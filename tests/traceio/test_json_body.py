"""traceio.reader._datagram_body reads a captured datagram's JSON body through orjson where
orjson gives what json gives, and through json everywhere else: of what the reader uses (the
body is a dict, ``peer``, ``local``, ``raw_base64``, ``run_delay_ns``) the same value, or json's
error, for any body (issue 17: a quarter of ``check``'s time on a million datagrams was json's)."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mcp_conform.traceio.reader import _datagram_body
from tests.tiers import examples

USED = ("peer", "local", "raw_base64", "run_delay_ns")
scalars = (st.none() | st.booleans() | st.integers(min_value=-(2**80), max_value=2**80)
           | st.floats(allow_nan=True, allow_infinity=True) | st.text())
values = st.recursive(scalars, lambda kids: st.lists(kids, max_size=4)
                      | st.dictionaries(st.text(max_size=8), kids, max_size=4), max_leaves=20)
bodies = values | st.fixed_dictionaries({}, optional={k: values for k in (*USED, "seq", "t_ns")})


def _same(a: object, b: object) -> bool:
    """Equal and of the same type, NaN equal to NaN, -0.0 told from 0.0."""
    if isinstance(a, float) and isinstance(b, float):
        return (math.isnan(a) and math.isnan(b)) or (a == b and math.copysign(1, a) == math.copysign(1, b))
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    return type(a) is type(b) and a == b


def _used(body: object) -> object:
    """What the reader takes of a body: of a dict, ``peer``, ``local`` and ``raw_base64`` where
    they are strings (anything else is no address, or a skipped record) and ``run_delay_ns``
    where it is a whole number >= 0; of anything else, that it is not a dict (a skipped record)."""
    if not isinstance(body, dict):
        return "not a dict"
    got: list[object] = [body[k] if isinstance(body.get(k), str) else ("absent" if k not in body else "not a string")
                         for k in USED[:3]]
    delay = body.get("run_delay_ns")
    return [*got, delay if type(delay) is int and delay >= 0 else None]


def _check(data: bytes) -> None:
    try:
        want = json.loads(data)
    except (ValueError, RecursionError) as exc:
        with pytest.raises(type(exc)):
            _datagram_body(data)
        return
    got = _datagram_body(data)
    assert _same(_used(got), _used(want)), data


@pytest.mark.parametrize("count", examples(full=400, quick=100))
def test_any_json_body_reads_as_json_reads_it(count: int) -> None:
    @settings(max_examples=count, deadline=None)
    @given(bodies, st.booleans())
    def prop(value: object, ascii_only: bool) -> None:
        _check(json.dumps(value, ensure_ascii=ascii_only).encode("utf-8", "surrogatepass"))

    prop()


@pytest.mark.parametrize("data", [
    b'{"run_delay_ns": 1e999}', b'{"run_delay_ns": NaN}', b'{"peer": Infinity}',
    b'{"run_delay_ns": 18446744073709551616}', b'{"run_delay_ns": 18446744073709551615}',
    b'{"run_delay_ns": -9223372036854775809}', b'{"run_delay_ns": 123456789012345678901234567890}',
    b'{"run_delay_ns": 1800000000000000000}', b'{"peer": "\\ud800"}', b'{"peer": "a", "peer": "b"}',
    b'{"run_delay_ns": -0}', b'{"run_delay_ns": 5.0}', '{"peer": "é"}'.encode("utf-16"),
    b'\xef\xbb\xbf{"peer": "x"}', b'{"peer": "\xff"}', b"{", b"", b"[1,]", b"[" * 5000 + b"]" * 5000,
    b'{"peer": "x"} trailing', b"[1, 2]", b'"a string"',
])
def test_what_orjson_refuses_or_reads_otherwise_reads_as_json_reads_it(data: bytes) -> None:
    _check(data)
