"""``mcp-capture dissector [--install]``: a Wireshark Lua dissector generated from the spec.

Everything in the generated ``centmesh.lua`` comes from ``spec/mcp.yaml``: the header
fields and their offsets, the preamble, the action codes and their names, each action's
payload kind, the mission-item layout (MAVLink v1 MISSION_ITEM, little-endian, E-1), the
conventional ports and the texts of the robustness rules the expert info names.

The protocol is ``centmesh``, not ``mcp``: Wireshark already has a built-in ``mcp`` (the
Miscabling Protocol) and a Lua ``Proto("mcp")`` fails to load. Fields: ``centmesh.preamble``,
``.dst``, ``.src``, ``.seq``, ``.action`` (with the description's names), ``.ready_id``
(Mission_Ready's optional ID), ``.ack_seq`` (the ACK's acknowledged seq), ``.count``,
``.item`` with ``centmesh.item.<field>`` for every mission-item field, ``.mavlink`` (the
passthrough frame), ``.mavlink_msg`` (its message name). A mission item's ``command`` and
``frame`` show pymavlink's MAV_CMD and MAV_FRAME names (``captures.dissector_mavlink``).

Where MCP is recognised: on the spec's ports (7889, 7890) and those of the ``centmesh.ports``
preference; by a heuristic on the preamble's text on any UDP port, after which both ports of
that datagram are MCP's (so a malformed datagram later on the node's port is still ours); a
UDP datagram with no payload on such a port (no sub-dissector sees it) by a post-dissector.
Every malformed datagram gets expert info and ``centmesh.rule`` naming the rule our decoder
(``spec.codec``) names: MCP-ROB-1 (shorter than a header), MCP-ROB-2 (bad preamble),
MCP-ROB-3 (unknown action code), MCP-ROB-4 (payload that does not fit the action, a
Mission_Ready ID that is not its src), MCP-PAY-6 (a passthrough that is not one whole MAVLink
frame with a good CRC).

Request / response tracking (complete in a second pass: ``tshark -2``, or Wireshark's GUI):
an ACK from A to B of seq S answers B's datagram with seq S — the ACK shows ``centmesh.acks``
("acknowledges frame N", the latest copy before it), each copy of the command
``centmesh.acked_in`` and ``centmesh.ack_time_ms`` ("ACKed in frame M, +x ms"); the same
bytes again between the same endpoints are a retransmission (``centmesh.retransmission_of``,
expert note); an ACK of a seq no datagram carried gets an expert note. A Mav_Passthrough
frame is handed to mavgen's MAVLink dissector (``mavlink_proto``) when it is loaded.

``--install`` copies it, and mavgen's MAVLink dissector (``centmesh-mavlink.lua``), to the
user's personal Wireshark plugin folder (``~/.local/lib/wireshark/plugins/``, where
Wireshark ≥ 2.6 on Linux and macOS looks).
"""

from __future__ import annotations

import struct
import sys
from pathlib import Path
from typing import Any, TextIO

from mcp_conform.captures import dissector_mavlink as dm
from mcp_conform.spec import SPEC
from mcp_conform.spec.profiles import DEFAULT_PROTOCOL, add_protocol_option, pick, resolve

__all__ = ["FILENAME", "PROTOCOL", "generate", "plugin_dir", "register", "run"]

PROTOCOL = "centmesh"
FILENAME = "centmesh.lua"

#: mission-item fields shown with value names (pymavlink's enums, MAV_CMD and MAV_FRAME)
_ITEM_NAMES = {"command": ", mav_cmd", "frame": ", mav_frame"}
_TRACKING = """
-- request / response tracking, built on the first pass (tshark -2, or Wireshark's GUI)
local copies, first_copy, cmds, ack_of, acked, times, claimed, seen = {}, {}, {}, {}, {}, {}, {}, {}
function centmesh.init()
  copies, first_copy, cmds, ack_of, acked, times, claimed, seen = {}, {}, {}, {}, {}, {}, {}, {}
end

local mav_dissector = false
local function mavlink_dissector()
  if mav_dissector == false then
    local ok, d = pcall(Dissector.get, "mavlink_proto")
    mav_dissector = ok and d or nil
  end
  return mav_dissector
end

local function mavlink_name(frame)
  local n = frame:len()
  if n >= 10 and frame(0, 1):uint() == 0xFD then
    return mav_msg[frame(7, 3):le_uint()] or ("msgid " .. frame(7, 3):le_uint())
  elseif n >= 6 and frame(0, 1):uint() == 0xFE then
    return mav_msg[frame(5, 1):uint()] or ("msgid " .. frame(5, 1):uint())
  end
  return nil
end

-- retransmissions (the same bytes between the same endpoints), which ACK answers which command
-- (an ACK from A to B of seq S answers B's datagram with seq S), and the time it took
local function track(tvb, pinfo, t, src, dst, seq, ack_seq)
  local n = pinfo.number
  if not pinfo.visited then
    times[n] = pinfo.abs_ts
    local key = tostring(pinfo.src) .. ":" .. pinfo.src_port .. ">" .. tostring(pinfo.dst) .. ":"
      .. pinfo.dst_port .. "|" .. tostring(tvb:bytes())
    if copies[key] then first_copy[n] = copies[key] else copies[key] = n end
    if ack_seq == nil then
      local c = src .. ":" .. seq
      cmds[c] = cmds[c] or {}
      table.insert(cmds[c], n)
    else
      local sent = cmds[dst .. ":" .. ack_seq]
      if sent then
        ack_of[n] = sent[#sent]
        for _, m in ipairs(sent) do
          if acked[m] == nil then acked[m] = {n, (pinfo.abs_ts - times[m]) * 1000} end
        end
      end
    end
  end
  local extra = ""
  if first_copy[n] then
    t:add(f.retransmission_of, first_copy[n]):set_generated()
    t:add_proto_expert_info(e_retransmission, "Retransmission of frame " .. first_copy[n])
    extra = extra .. " [retransmission of frame " .. first_copy[n] .. "]"
  end
  if ack_seq ~= nil then
    if ack_of[n] then
      t:add(f.acks, ack_of[n]):set_generated()
      extra = extra .. " (acknowledges frame " .. ack_of[n] .. ")"
    else
      t:add_proto_expert_info(e_ack_unknown, "ACK of seq " .. ack_seq .. ": no datagram from " .. dst
        .. " with that seq before it in this capture")
    end
  elseif acked[n] then
    t:add(f.acked_in, acked[n][1]):set_generated()
    t:add(f.ack_time, acked[n][2]):set_generated()
    extra = extra .. string.format(" [ACKed in frame %d, +%.1f ms]", acked[n][1], acked[n][2])
  end
  return extra
end
"""

#: MCP-PAY-6 as spec.mavframe.parse_frame judges it: one whole MAVLink v1/v2 frame of a message
#: the dialect knows, with a good CRC (X.25 with the message's CRC_EXTRA); a message of another
#: dialect has no checksum valid "under the ardupilotmega dialect" (pymavlink passes it unchecked)
_FRAME_CHECK = """
local function x25(tvb, from, to, extra)
  local crc = 0xFFFF
  local function acc(b)
    local tmp = bit.band(bit.bxor(b, bit.band(crc, 0xFF)), 0xFF)
    tmp = bit.band(bit.bxor(tmp, bit.lshift(tmp, 4)), 0xFF)
    crc = bit.band(bit.bxor(bit.rshift(crc, 8), bit.lshift(tmp, 8), bit.lshift(tmp, 3), bit.rshift(tmp, 4)), 0xFFFF)
  end
  for i = from, to - 1 do acc(tvb(i, 1):uint()) end
  acc(extra)
  return crc
end

local function frame_problem(frame)
  local n = frame:len()
  local magic = frame(0, 1):uint()
  local hlen, plen, msgid, signed
  if magic == 0xFE then
    if n < 8 then return "incomplete MAVLink frame: " .. n .. " bytes" end
    hlen, plen, msgid, signed = 6, frame(1, 1):uint(), frame(5, 1):uint(), 0
  elseif magic == 0xFD then
    if n < 12 then return "incomplete MAVLink frame: " .. n .. " bytes" end
    hlen, plen, msgid = 10, frame(1, 1):uint(), frame(7, 3):le_uint()
    signed = (bit.band(frame(2, 1):uint(), 1) ~= 0) and 13 or 0
  else
    return string.format("starts with 0x%02X, not a MAVLink v1 (0xFE) or v2 (0xFD) marker", magic)
  end
  local want = hlen + plen + 2 + signed
  if n < want then return "incomplete MAVLink frame: " .. n .. " of " .. want .. " bytes" end
  if n > want then return (n - want) .. " byte(s) after the MAVLink frame" end
  local extra = mav_crc_extra[msgid]
  if extra == nil then  -- a message of another dialect: no CRC_EXTRA, so no checksum of it is valid
    return "MAVLink message id " .. msgid .. " is not in the ardupilotmega dialect: no checksum of it is valid"
  end
  if x25(frame, 1, hlen + plen, extra) ~= frame(hlen + plen, 2):le_uint() then
    return "bad MAVLink frame: CRC mismatch (" .. (mav_msg[msgid] or msgid) .. ")"
  end
  return nil
end
"""

#: A UDP datagram with no payload reaches no UDP sub-dissector: a post-dissector marks one on an
#: MCP port (the spec's, the preference's, or one the heuristic claimed) as MCP-ROB-1.
_EMPTY = """
local udp_length = Field.new("udp.length")
local centmesh_empty = Proto("centmesh_empty", "CentMesh: UDP datagrams without a payload on an MCP port")
local function pref_has(p)
  for a, b in string.gmatch(tostring(centmesh.prefs.ports or ""), "(%d+)%-?(%d*)") do
    local lo = tonumber(a)
    local hi = tonumber(b) or lo
    if p >= lo and p <= hi then return true end
  end
  return false
end
function centmesh_empty.dissector(tvb, pinfo, tree)
  if seen[pinfo.number] then return end
  local ulen = udp_length()
  if ulen == nil or ulen.value ~= 8 then return end
  local sp, dp = pinfo.src_port, pinfo.dst_port
  if not (claimed[sp] or claimed[dp] or pref_has(sp) or pref_has(dp)) then return end
  local t = tree:add(centmesh):set_text("CentMesh Mission Control Protocol: malformed (MCP-ROB-1)")
  t:add_proto_expert_info(e_mcp_rob_1, "MCP-ROB-1: 0 bytes, shorter than the " .. HEADER_SIZE .. "-byte header")
  t:add(f.rule, "MCP-ROB-1"):set_generated()
  pinfo.cols.protocol = "CentMesh"
  pinfo.cols.info = "MCP malformed: 0 bytes (MCP-ROB-1)"
end
register_postdissector(centmesh_empty)
"""

_LUA_INT = {"B": ("uint8", 1), "H": ("uint16", 2), "I": ("uint32", 4), "b": ("int8", 1),
            "h": ("int16", 2), "i": ("int32", 4), "f": ("float", 4), "d": ("double", 8)}


def _lua_str(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"').replace("\n", " ") + '"'


def _header_fields() -> list[tuple[str, int, int, str]]:
    """(name, offset, size, doc) of the header's non-constant fields, from its struct."""
    fmt = SPEC.header["struct"]
    order, codes = fmt[0], fmt[1:]
    out = []
    offset = struct.calcsize(order + "".join(f["code"] for f in SPEC.header["fields"] if "const" in f))
    for f in SPEC.header["fields"]:
        if "const" in f:
            continue
        size = struct.calcsize(order + f["code"])
        out.append((f["name"], offset, size, f.get("doc", f["name"])))
        offset += size
    assert offset == struct.calcsize(fmt), (codes, offset)
    return out


def _item_fields() -> list[tuple[str, str, int, int, str]]:
    """(name, lua type, offset, size, doc) of the mission item's fields."""
    fmt = SPEC.mission_item["struct"]
    order = fmt[0]
    out = []
    offset = 0
    for f in SPEC.mission_item["fields"]:
        lua, size = _LUA_INT[f["code"]]
        assert struct.calcsize(order + f["code"]) == size
        out.append((f["name"], lua, offset, size, f.get("doc", f["name"])))
        offset += size
    return out


def generate() -> str:
    """The Lua source of the dissector."""
    header = _header_fields()
    items = _item_fields()
    item_size = int(SPEC.mission_item["size"])
    item_le = SPEC.mission_item["struct"][0] == "<"
    hsize = struct.calcsize(SPEC.header["struct"])
    preamble = SPEC.preamble
    text_len = len(SPEC.header["fields"][0]["const"])
    ports = sorted(int(p) for p in SPEC.protocol["ports"].values())
    wire = [a for a in SPEC.actions if a.on_wire]
    kinds = {a.code: a.payload_kind for a in wire}
    rob = {r: SPEC.rule(r).text for r in ("MCP-ROB-1", "MCP-ROB-2", "MCP-ROB-3", "MCP-ROB-4", "MCP-PAY-6")}
    add_item = "add_le" if item_le else "add"
    L: list[str] = []
    w = L.append
    w(f"-- {FILENAME}: Wireshark dissector for the {SPEC.protocol['name']} ({SPEC.protocol['short_name']}).")
    w(f"-- Generated by `mcp-capture dissector` from spec/mcp.yaml (document version {SPEC.version},")
    w(f"-- spec sha256 {SPEC.sha256}). Do not edit: regenerate.")
    w("-- Protocol name 'centmesh': Wireshark's built-in 'mcp' is the Miscabling Protocol.")
    w("")
    w(f'local centmesh = Proto("{PROTOCOL}", {_lua_str(SPEC.protocol["name"])})')
    w("local actions = {")
    for a in wire:
        w(f"  [{a.code}] = {_lua_str(a.wire_name)},")
    w("}")
    w("local kinds = {")
    for code, kind in kinds.items():
        w(f'  [{code}] = "{kind}",')
    w("}")
    w(dm.lua_table("mav_cmd", dm.enum_names("MAV_CMD")))
    w(dm.lua_table("mav_frame", dm.enum_names("MAV_FRAME")))
    w(dm.lua_table("mav_msg", dm.message_names()))
    w(dm.lua_table("mav_crc_extra", dm.crc_extras()))
    w(_FRAME_CHECK)
    w("local f = centmesh.fields")
    w(f'f.preamble = ProtoField.bytes("{PROTOCOL}.preamble", "Preamble")')
    for name, _off, size, doc in header:
        lua = {1: "uint8", 2: "uint16", 4: "uint32"}[size]
        extra = ", base.DEC, actions" if name == "action" else ", base.DEC"
        w(f'f.{name} = ProtoField.{lua}("{PROTOCOL}.{name}", {_lua_str(doc)}{extra})')
    w(f'f.ready_id = ProtoField.uint16("{PROTOCOL}.ready_id", "Mission_Ready: the drone\'s ID", base.DEC)')
    w(f'f.ack_seq = ProtoField.uint16("{PROTOCOL}.ack_seq", "ACK: acknowledged sequence number", base.DEC)')
    w(f'f.count = ProtoField.uint16("{PROTOCOL}.count", "Number of mission items", base.DEC)')
    w(f'f.item = ProtoField.bytes("{PROTOCOL}.item", "Mission item")')
    for name, lua, _off, _size, doc in items:
        base = "" if lua in ("float", "double") else ", base.DEC" + _ITEM_NAMES.get(name, "")
        w(f'f.item_{name} = ProtoField.{lua}("{PROTOCOL}.item.{name}", {_lua_str(doc)}{base})')
    w(f'f.mavlink = ProtoField.bytes("{PROTOCOL}.mavlink", "Mav_Passthrough: MAVLink frame")')
    w(f'f.payload = ProtoField.bytes("{PROTOCOL}.payload", "Payload")')
    w(f'f.mavlink_msg = ProtoField.string("{PROTOCOL}.mavlink_msg", "Mav_Passthrough: MAVLink message")')
    w(f'f.acks = ProtoField.framenum("{PROTOCOL}.acks", "Acknowledges frame", base.NONE, frametype.REQUEST)')
    w(f'f.acked_in = ProtoField.framenum("{PROTOCOL}.acked_in", "ACKed in frame", base.NONE, frametype.ACK)')
    w(f'f.ack_time = ProtoField.double("{PROTOCOL}.ack_time_ms", "Time to the ACK (ms)")')
    w(f'f.retransmission_of = ProtoField.framenum("{PROTOCOL}.retransmission_of", "Retransmission of frame", '
      "base.NONE, frametype.RETRANS_PREV or frametype.NONE)")
    w(f'f.rule = ProtoField.string("{PROTOCOL}.rule", "Rule broken")')
    for rule, text in rob.items():
        var = "e_" + rule.replace("-", "_").lower()
        w(f'local {var} = ProtoExpert.new("{PROTOCOL}.{rule.lower().replace("-", "_")}", '
          f'{_lua_str(rule + ": " + text)}, expert.group.MALFORMED, expert.severity.ERROR)')
    w(f'local e_retransmission = ProtoExpert.new("{PROTOCOL}.retransmission", "Retransmission: the same '
      'datagram again (MCP-REL-1 retransmits an unACKed message every RTO)", expert.group.SEQUENCE, '
      'expert.severity.NOTE)')
    w(f'local e_ack_unknown = ProtoExpert.new("{PROTOCOL}.ack_unknown", "ACK of a seq no command in this '
      'capture carried", expert.group.SEQUENCE, expert.severity.NOTE)')
    w("centmesh.experts = { " + ", ".join("e_" + r.replace("-", "_").lower() for r in rob)
      + ", e_retransmission, e_ack_unknown }")
    w("")
    w("-- ports: the spec's, any set in the preferences, and those of a conversation the heuristic")
    w("-- recognised (so a malformed datagram later on the same port is still ours)")
    w(f'centmesh.prefs.ports = Pref.range("UDP ports", "{",".join(str(p) for p in ports)}", '
      '"UDP ports always dissected as CentMesh MCP", 65535)')
    w(_TRACKING)
    w("")
    w(f'local PREAMBLE = "{preamble.hex().upper()}"')
    w(f"local PREAMBLE_TEXT_LEN = {text_len}")
    w(f"local HEADER_SIZE = {hsize}")
    w(f"local ITEM_SIZE = {item_size}")
    w("")
    w("local function add_item(tree, tvb, offset, label)")
    w('  local t = tree:add(f.item, tvb(offset, ITEM_SIZE)):set_text(label)')
    for name, _lua, off, size, _doc in items:
        w(f"  t:{add_item}(f.item_{name}, tvb(offset + {off}, {size}))")
    w("end")
    w("")
    w("function centmesh.dissector(tvb, pinfo, tree)")
    w("  local len = tvb:len()")
    w("  seen[pinfo.number] = true")
    w('  pinfo.cols.protocol = "CentMesh"')
    w("  local t = tree:add(centmesh, tvb())")
    w("  if len < HEADER_SIZE then")
    w('    t:add_proto_expert_info(e_mcp_rob_1, "MCP-ROB-1: " .. len .. " bytes, shorter than the " .. HEADER_SIZE .. "-byte header")')
    w('    t:add(f.rule, "MCP-ROB-1"):set_generated()')
    w('    pinfo.cols.info = "MCP malformed: " .. len .. " bytes (MCP-ROB-1)"')
    w('    t:append_text(": malformed (MCP-ROB-1)")')
    w("    return len")
    w("  end")
    w("  local pre = t:add(f.preamble, tvb(0, #PREAMBLE / 2))")
    w("  local bad = {}")
    w("  if tostring(tvb(0, #PREAMBLE / 2):bytes()) ~= PREAMBLE then")
    w('    pre:add_proto_expert_info(e_mcp_rob_2)')
    w('    bad[#bad + 1] = "MCP-ROB-2"')
    w("  end")
    for name, off, size, _doc in header:
        w(f"  t:add(f.{name}, tvb({off}, {size}))")
    by_name = {name: (off, size) for name, off, size, _ in header}
    for name in ("dst", "src", "seq", "action"):
        off, size = by_name[name]
        w(f"  local {name} = tvb({off}, {size}):uint()")
    w("  local plen = len - HEADER_SIZE")
    w("  local kind = kinds[action]")
    w('  local name = actions[action] or ("action " .. action)')
    w('  local info = name .. " " .. src .. "→" .. dst .. " seq=" .. seq')
    w("  local function misfit(why)")
    w('    t:add_proto_expert_info(e_mcp_rob_4, "MCP-ROB-4: " .. why)')
    w('    bad[#bad + 1] = "MCP-ROB-4"')
    w("  end")
    w("  if kind == nil then")
    w('    t:add_proto_expert_info(e_mcp_rob_3, "MCP-ROB-3: unknown action code " .. action)')
    w('    bad[#bad + 1] = "MCP-ROB-3"')
    w('    if plen > 0 then t:add(f.payload, tvb(HEADER_SIZE, plen)) end')
    w('  elseif kind == "empty" then')
    w('    if plen ~= 0 then misfit(name .. " carries no payload, got " .. plen .. " bytes") end')
    w('  elseif kind == "optional_id" then')
    w("    if plen == 2 then")
    w("      t:add(f.ready_id, tvb(HEADER_SIZE, 2))")
    w("      if tvb(HEADER_SIZE, 2):uint() ~= src then")
    w('        misfit(name .. " carries ID " .. tvb(HEADER_SIZE, 2):uint() .. " but src is " .. src .. " (D-3)")')
    w("      end")
    w("    elseif plen ~= 0 then")
    w('      misfit(name .. " payload is empty or 2 bytes, got " .. plen)')
    w("    end")
    w('  elseif kind == "seq" then')
    w("    if plen == 2 then")
    w("      t:add(f.ack_seq, tvb(HEADER_SIZE, 2))")
    w('      info = info .. " ack=" .. tvb(HEADER_SIZE, 2):uint()')
    w("    else")
    w('      misfit("an ACK payload is 2 bytes, got " .. plen)')
    w("    end")
    w('  elseif kind == "counted_items" then')
    w("    if plen < 2 then")
    w('      misfit(name .. " needs a 2-byte count, got " .. plen .. " bytes")')
    w("    else")
    w("      local count = tvb(HEADER_SIZE, 2):uint()")
    w("      t:add(f.count, tvb(HEADER_SIZE, 2))")
    w('      info = info .. " count=" .. count')
    w("      if plen ~= 2 + count * ITEM_SIZE then")
    w('        misfit("count " .. count .. " needs " .. (2 + count * ITEM_SIZE) .. " payload bytes, got " .. plen)')
    w("      end")
    w("      local i = 0")
    w("      while i < count and HEADER_SIZE + 2 + (i + 1) * ITEM_SIZE <= len do")
    w('        add_item(t, tvb, HEADER_SIZE + 2 + i * ITEM_SIZE, "Mission item " .. i)')
    w("        i = i + 1")
    w("      end")
    w("    end")
    w('  elseif kind == "single_item" then')
    w("    if plen == ITEM_SIZE then")
    w('      add_item(t, tvb, HEADER_SIZE, "Mission item")')
    w("    else")
    w('      misfit(name .. " carries one " .. ITEM_SIZE .. "-byte item, got " .. plen .. " bytes")')
    w("    end")
    w('  elseif kind == "mavlink_frame" then')
    w("    if plen > 0 then")
    w("      t:add(f.mavlink, tvb(HEADER_SIZE, plen))")
    w("      local mname = mavlink_name(tvb(HEADER_SIZE, plen))")
    w("      if mname then")
    w("        t:add(f.mavlink_msg, tvb(HEADER_SIZE, plen), mname):set_generated()")
    w('        info = info .. " [MAVLink " .. mname .. "]"')
    w("      end")
    w("      local why = frame_problem(tvb(HEADER_SIZE, plen))")
    w("      if why then")
    w('        t:add_proto_expert_info(e_mcp_pay_6, "MCP-PAY-6: " .. why)')
    w('        bad[#bad + 1] = "MCP-PAY-6"')
    w("      end")
    w("      local mav = mavlink_dissector()")
    w("      if mav then")
    w("        local csrc, cdst = tostring(pinfo.cols.src), tostring(pinfo.cols.dst)")
    w("        pcall(function() mav:call(tvb(HEADER_SIZE, plen):tvb(), pinfo, tree) end)")
    w("        pinfo.cols.src, pinfo.cols.dst = csrc, cdst  -- mavgen's puts system and message there")
    w("      end")
    w("    else")
    w('      t:add_proto_expert_info(e_mcp_pay_6, "MCP-PAY-6: " .. name .. " carries one MAVLink frame, got none")')
    w('      bad[#bad + 1] = "MCP-PAY-6"')
    w("    end")
    w("  end")
    w("  for _, rule in ipairs(bad) do t:add(f.rule, rule):set_generated() end")
    w("  if #bad > 0 then")
    w('    info = info .. " [malformed: " .. table.concat(bad, ", ") .. "]"')
    w("  end")
    w('  local ack_seq = (kind == "seq" and plen == 2) and tvb(HEADER_SIZE, 2):uint() or nil')
    w("  info = info .. track(tvb, pinfo, t, src, dst, seq, ack_seq)")
    w('  t:append_text(": " .. info)')
    w('  pinfo.cols.protocol = "CentMesh"')
    w("  pinfo.cols.info = info")
    w("  return len")
    w("end")
    w("")
    w("-- any UDP port: the preamble's text starts the datagram")
    w("local function heuristic(tvb, pinfo, tree)")
    w("  if tvb:len() < PREAMBLE_TEXT_LEN then return false end")
    w("  if tostring(tvb(0, PREAMBLE_TEXT_LEN):bytes()) ~= PREAMBLE:sub(1, 2 * PREAMBLE_TEXT_LEN) then return false end")
    w("  centmesh.dissector(tvb, pinfo, tree)")
    w("  claim_ports(pinfo)")
    w("  return true")
    w("end")
    w('centmesh:register_heuristic("udp", heuristic)')
    w('local udp_port = DissectorTable.get("udp.port")')
    for p in ports:
        w(f"udp_port:add({p}, centmesh)  -- {', '.join(k for k, v in SPEC.protocol['ports'].items() if int(v) == p)} (MCP-TRN-1)")
    w("local pref_ports = nil")
    w("function centmesh.prefs_changed()")
    w("  if pref_ports then udp_port:remove(pref_ports, centmesh) end")
    w("  pref_ports = centmesh.prefs.ports")
    w('  if pref_ports and tostring(pref_ports) ~= "" then udp_port:add(pref_ports, centmesh) end')
    w("end")
    w(_EMPTY)
    w("function claim_ports(pinfo)")
    w("  for _, p in ipairs({pinfo.src_port, pinfo.dst_port}) do")
    w("    if not claimed[p] then claimed[p] = true; udp_port:add(p, centmesh) end")
    w("  end")
    w("end")
    return "\n".join(L) + "\n"


def plugin_dir() -> Path:
    """The personal Lua plugin folder of Wireshark on Linux and macOS."""
    return Path.home() / ".local" / "lib" / "wireshark" / "plugins"


def register(sub: Any) -> None:
    p = sub.add_parser("dissector", help="print the Wireshark Lua dissector (protocol centmesh)",
                       description="Print the Wireshark Lua dissector generated from spec/mcp.yaml, "
                                   "or install it (--install).")
    p.add_argument("--install", action="store_true",
                   help=f"copy it to {plugin_dir()}/{FILENAME} instead of printing it")
    p.add_argument("-o", "--output", metavar="FILE", help="write it to FILE instead of printing it")
    p.add_argument("--mavlink", metavar="FILE", dest="mavlink_output",
                   help=f"also write the MAVLink dissector (pymavlink's mavgen --lang=WLua) to FILE; "
                        f"--install writes it as {dm.FILENAME}")
    add_protocol_option(p, "mcp (default: centmesh.lua), nsqd (nsqd.lua, the Nsqd TCP protocol) or mavlink "
                           f"({dm.FILENAME}, pymavlink's mavgen --lang=WLua): the dissector its profile names",
                        default=DEFAULT_PROTOCOL, needs="dissector")
    p.set_defaults(run=run)


def run(args: Any, out: TextIO | None = None, err: TextIO | None = None) -> int:
    out = out or sys.stdout
    err = err or sys.stderr
    dissector = resolve(pick(getattr(args, "protocol", DEFAULT_PROTOCOL))[0].dissector)
    source, filename = dissector.generate(), dissector.FILENAME
    target: Path | None = None
    writes: list[tuple[Path, str | None]] = []
    if args.install:
        target = plugin_dir() / filename
    elif args.output:
        target = Path(args.output)
    if target is not None:
        writes.append((target, source))
    mav_target = getattr(args, "mavlink_output", None)
    if filename == FILENAME and (args.install or mav_target):
        # Mav_Passthrough payloads: mavgen's MAVLink dissector beside ours (made when written)
        writes.append((plugin_dir() / dm.FILENAME if args.install else Path(mav_target), None))  # type: ignore[arg-type]  # set (the condition)
    if target is None:
        out.write(source)
    for path, text in writes:
        try:
            if args.install:
                path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(dm.generate_wlua() if text is None else text, encoding="utf-8")
        except OSError as exc:
            err.write(f"mcp-capture: error: dissector: cannot write {path}: {exc.strerror}\n")
            return 2
        except RuntimeError as exc:
            err.write(f"mcp-capture: error: dissector: {exc}\n")
            return 2
        out.write(f"wrote {path}\n")
    if writes and target is not None:
        scripts = " ".join(f"-X lua_script:{p}" for p, _ in reversed(writes))
        out.write(f"restart Wireshark, or: tshark -2 {scripts} -r CAPTURE.pcapng\n")
    return 0
