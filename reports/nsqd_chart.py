"""Sequence charts of a stream protocol's run (``--protocol nsqd``): the runner's
connections and the backend as lifelines, each frame an arrow (reports.chart draws them).

The backend's UPDATE stream is shown as it is, one arrow per frame, but a run of UPDATEs
with the same state is folded into its first and a count, so a chart shows what the case
did and what changed, not 2.5 arrows a second.
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence

from mcp_conform.reports.chart import Arrow, Lifeline, render
from mcp_conform.spec import NSQD
from mcp_conform.spec.nsqd_codec import BodyError, decode_body
from mcp_conform.traceio.reader import StreamFrame

__all__ = ["stream_svg"]

#: the lifeline of the node under test, named by its role (the spec's first: the backend)
_NODE = Lifeline("node", NSQD.roles[0])


def _label(f: StreamFrame) -> str:
    if f.problem and not f.name:
        return f"{len(f.raw)} B: {f.problem}"[:60]
    name = f.name or (f"{len(f.raw)} B" if f.direction == "tx" else "frame")
    if name == "UPDATE" and not f.problem:  # the state, read by the spec's layout
        body = f.raw[NSQD.framing.header_size:]
        with contextlib.suppress(BodyError, KeyError):
            return f"UPDATE state={decode_body(NSQD, NSQD.message('UPDATE').id, body, check_text=False)['state']}"
    return name + (f" ({f.problem})" if f.problem else "")


def stream_svg(frames: Sequence[StreamFrame], title: str = "") -> str:
    """The chart of ``frames`` (one case's window, say)."""
    conns = sorted({f.conn for f in frames})
    lifelines = [Lifeline(f"c{c}", f"runner conn {c}") for c in conns] + [_NODE]
    arrows: list[Arrow] = []
    folded = 0
    for f in frames:
        label = _label(f)
        if f.direction == "rx" and arrows and arrows[-1].src == _NODE.key and arrows[-1].dst == f"c{f.conn}" \
                and arrows[-1].label.split(" ×")[0] == label:
            folded += 1
            last = arrows[-1]
            arrows[-1] = last._replace(label=f"{label} ×{folded + 1}")
            continue
        folded = 0
        kind = "malformed" if f.problem else "msg"
        src, dst = (f"c{f.conn}", _NODE.key) if f.direction == "tx" else (_NODE.key, f"c{f.conn}")
        arrows.append(Arrow(f.t_ns, src, dst, label, kind=kind, note=f.raw[:48].hex(" "), index=f.index))
    return render(lifelines, arrows, title=title)
