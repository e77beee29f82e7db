"""Write the MAVLink dialect the JavaScript drone reads at start (drone.js --dialect FILE).

    python gen_dialect.py OUT.json [DIALECT]     (DIALECT: ardupilotmega, the default)

Reads pymavlink's dialect XML (and the files it includes) and writes, per message id, its
name, CRC_EXTRA and fields in wire order (type, array length; extension fields last), the
layout drone.js packs and checks frames by. Nothing generated is kept in the source tree.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import sys

import pymavlink
from pymavlink.generator import mavparse


def load(name: str) -> dict[int, dict]:
    base = os.path.join(os.path.dirname(pymavlink.__file__), "dialects", "v20")
    seen: set[str] = set()
    messages: dict[int, dict] = {}

    def parse(fname: str) -> None:
        if fname in seen:
            return
        seen.add(fname)
        with contextlib.redirect_stdout(io.StringIO()):  # mavparse prints its XML warnings
            xml = mavparse.MAVXML(os.path.join(base, fname), "2.0")
        for inc in xml.include:
            parse(inc)
        for m in xml.message:
            ext = m.extensions_start
            fields = [[f.name, f.type, f.array_length, bool(ext is not None and f.name in
                                                             {e.name for e in m.fields[ext:]})]
                      for f in m.ordered_fields]
            messages[m.id] = {"name": m.name, "crc_extra": m.crc_extra, "fields": fields,
                              "min_length": m.wire_min_length, "length": m.wire_length}

    parse(name + ".xml")
    return messages


def main() -> None:
    out = sys.argv[1]
    dialect = sys.argv[2] if len(sys.argv) > 2 else "ardupilotmega"
    with open(out, "w", encoding="utf-8") as f:
        json.dump({"dialect": dialect, "messages": load(dialect)}, f)


if __name__ == "__main__":
    main()
