'use strict';
// A small MAVLink 2 codec and link for the drone, no npm packages. Message layouts and
// CRC_EXTRAs come from a JSON file written by gen_dialect.py from pymavlink's dialect XML.

const fs = require('fs');
const net = require('net');
const dgram = require('dgram');
const { EventEmitter } = require('events');

const SIZES = { char: 1, int8_t: 1, uint8_t: 1, uint8_t_mavlink_version: 1, int16_t: 2, uint16_t: 2,
  int32_t: 4, uint32_t: 4, float: 4, int64_t: 8, uint64_t: 8, double: 8 };

// CRC-16/MCRF4XX (X.25 as MAVLink uses it)
function crcAccumulate(byte, crc) {
  let tmp = (byte ^ (crc & 0xff)) & 0xff;
  tmp = (tmp ^ (tmp << 4)) & 0xff;
  return ((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xffff;
}

function crc16(buf, start, end, extra) {
  let crc = 0xffff;
  for (let i = start; i < end; i++) crc = crcAccumulate(buf[i], crc);
  if (extra !== undefined) crc = crcAccumulate(extra, crc);
  return crc;
}

class Dialect {
  constructor(file) {
    const doc = JSON.parse(fs.readFileSync(file, 'utf8'));
    this.byId = new Map();
    this.byName = new Map();
    for (const [id, m] of Object.entries(doc.messages)) {
      const msg = { id: Number(id), ...m };
      this.byId.set(msg.id, msg);
      this.byName.set(msg.name, msg);
    }
  }

  pack(name, values) {
    const m = this.byName.get(name);
    if (!m) throw new Error(`no message ${name} in the dialect`);
    const buf = Buffer.alloc(m.length);
    let off = 0;
    for (const [field, type, arrayLen] of m.fields) {
      const n = arrayLen || 1;
      const size = SIZES[type];
      for (let i = 0; i < n; i++) {
        let v = values[field];
        if (arrayLen) v = v === undefined ? 0 : (typeof v === 'string' ? v.charCodeAt(i) || 0 : v[i] || 0);
        if (v === undefined) v = 0;
        writeValue(buf, off, type, v);
        off += size;
      }
    }
    // MAVLink 2 payload truncation: trailing zero bytes are left off (at least one byte kept)
    let len = buf.length;
    while (len > 1 && buf[len - 1] === 0) len--;
    return { msg: m, payload: buf.subarray(0, len) };
  }

  unpack(msgid, payload) {
    const m = this.byId.get(msgid);
    if (!m) return null;
    const buf = Buffer.alloc(Math.max(m.length, payload.length));
    payload.copy(buf);
    const out = { _name: m.name, _id: msgid };
    let off = 0;
    for (const [field, type, arrayLen] of m.fields) {
      const size = SIZES[type];
      if (arrayLen) {
        const arr = [];
        for (let i = 0; i < arrayLen; i++) { arr.push(readValue(buf, off, type)); off += size; }
        out[field] = type === 'char' ? String.fromCharCode(...arr).replace(/\0.*$/, '') : arr;
      } else {
        out[field] = readValue(buf, off, type);
        off += size;
      }
    }
    return out;
  }

  // Is buf exactly one complete MAVLink v1 or v2 frame, its checksum valid under this dialect?
  isOneFrame(buf) {
    if (buf.length < 8) return false;
    let total; let msgid; let crcEnd;
    if (buf[0] === 0xfe) {
      total = 8 + buf[1];
      msgid = buf[5];
      crcEnd = 6 + buf[1];
    } else if (buf[0] === 0xfd) {
      if (buf.length < 12) return false;
      if (buf[2] & ~0x01) return false;  // an incompatibility flag this codec does not know
      total = 12 + buf[1] + ((buf[2] & 0x01) ? 13 : 0);
      msgid = buf[7] | (buf[8] << 8) | (buf[9] << 16);
      crcEnd = 10 + buf[1];
    } else {
      return false;
    }
    if (buf.length !== total) return false;
    const m = this.byId.get(msgid);
    if (!m) return false;
    return crc16(buf, 1, crcEnd, m.crc_extra) === buf.readUInt16LE(crcEnd);
  }
}

function writeValue(buf, off, type, v) {
  switch (type) {
    case 'char': case 'uint8_t': case 'uint8_t_mavlink_version': buf.writeUInt8(v & 0xff, off); break;
    case 'int8_t': buf.writeInt8(v, off); break;
    case 'uint16_t': buf.writeUInt16LE(v & 0xffff, off); break;
    case 'int16_t': buf.writeInt16LE(v, off); break;
    case 'uint32_t': buf.writeUInt32LE(v >>> 0, off); break;
    case 'int32_t': buf.writeInt32LE(v | 0, off); break;
    case 'float': buf.writeFloatLE(v, off); break;
    case 'double': buf.writeDoubleLE(v, off); break;
    case 'uint64_t': buf.writeBigUInt64LE(BigInt(v), off); break;
    case 'int64_t': buf.writeBigInt64LE(BigInt(v), off); break;
    default: throw new Error(`type ${type}`);
  }
}

function readValue(buf, off, type) {
  switch (type) {
    case 'char': case 'uint8_t': case 'uint8_t_mavlink_version': return buf.readUInt8(off);
    case 'int8_t': return buf.readInt8(off);
    case 'uint16_t': return buf.readUInt16LE(off);
    case 'int16_t': return buf.readInt16LE(off);
    case 'uint32_t': return buf.readUInt32LE(off);
    case 'int32_t': return buf.readInt32LE(off);
    case 'float': return buf.readFloatLE(off);
    case 'double': return buf.readDoubleLE(off);
    case 'uint64_t': return buf.readBigUInt64LE(off);
    case 'int64_t': return buf.readBigInt64LE(off);
    default: throw new Error(`type ${type}`);
  }
}

// The autopilot link: tcp:HOST:PORT, udp:/udpin:HOST:PORT (we listen, the autopilot sends
// here; we answer its address), udpout:HOST:PORT (we send there). Emits 'message' (decoded,
// with _sys, _comp) for every frame with a valid checksum.
class Link extends EventEmitter {
  constructor(url, dialect, { sysid = 255, compid = 190 } = {}) {
    super();
    this.dialect = dialect;
    this.sysid = sysid;
    this.compid = compid;
    this.seq = 0;
    this.rx = Buffer.alloc(0);
    const m = /^(tcp|udp|udpin|udpout):([^:]+):(\d+)$/.exec(url);
    if (!m) throw new Error(`unsupported MAVLink URL ${url}`);
    const [, kind, host, port] = m;
    this.kind = kind;
    if (kind === 'tcp') {
      // connect, and again a second after the connection fails or ends (an autopilot, or
      // SITL, not up yet or restarted)
      const connect = () => {
        this.rx = Buffer.alloc(0);
        this.sock = net.connect(Number(port), host);
        this.sock.setNoDelay(true);
        this.sock.on('data', (d) => this.feed(d));
        this.sock.on('error', (e) => this.emit('error', e));
        this.sock.on('close', () => {
          if (!this.closing) this.retry = setTimeout(connect, 1000);
        });
      };
      connect();
    } else {
      this.sock = dgram.createSocket('udp4');
      this.sock.on('message', (d, rinfo) => {
        if (kind !== 'udpout') this.peer = { host: rinfo.address, port: rinfo.port };
        this.feed(d);
      });
      this.sock.on('error', (e) => this.emit('error', e));
      if (kind === 'udpout') {
        this.peer = { host, port: Number(port) };
        this.sock.bind(0);
      } else {
        this.sock.bind(Number(port), host);
      }
    }
  }

  writeRaw(frame) {
    if (this.kind === 'tcp') {
      if (!this.sock.destroyed) this.sock.write(frame);  // (lost while reconnecting, as on a wire)
    } else if (this.peer) {
      this.sock.send(frame, this.peer.port, this.peer.host);
    }
  }

  send(name, values) {
    const { msg, payload } = this.dialect.pack(name, values);
    const frame = Buffer.alloc(12 + payload.length);
    frame[0] = 0xfd;
    frame[1] = payload.length;
    frame[2] = 0;
    frame[3] = 0;
    frame[4] = this.seq;
    this.seq = (this.seq + 1) & 0xff;
    frame[5] = this.sysid;
    frame[6] = this.compid;
    frame[7] = msg.id & 0xff;
    frame[8] = (msg.id >> 8) & 0xff;
    frame[9] = (msg.id >> 16) & 0xff;
    payload.copy(frame, 10);
    frame.writeUInt16LE(crc16(frame, 1, 10 + payload.length, msg.crc_extra), 10 + payload.length);
    this.writeRaw(frame);
  }

  feed(data) {
    this.rx = this.rx.length ? Buffer.concat([this.rx, data]) : data;
    for (;;) {
      let i = 0;
      while (i < this.rx.length && this.rx[i] !== 0xfd && this.rx[i] !== 0xfe) i++;
      if (i) this.rx = this.rx.subarray(i);
      if (this.rx.length < 3) return;
      const v2 = this.rx[0] === 0xfd;
      const total = v2 ? 12 + this.rx[1] + ((this.rx[2] & 0x01) ? 13 : 0) : 8 + this.rx[1];
      if (this.rx.length < total) return;
      const frame = this.rx.subarray(0, total);
      if (!this.dialect.isOneFrame(frame)) {
        this.rx = this.rx.subarray(1);  // not a frame: resynchronise
        continue;
      }
      this.rx = this.rx.subarray(total);
      const hdr = v2 ? 10 : 6;
      const msgid = v2 ? frame[7] | (frame[8] << 8) | (frame[9] << 16) : frame[5];
      const msg = this.dialect.unpack(msgid, frame.subarray(hdr, hdr + frame[1]));
      msg._sys = v2 ? frame[5] : frame[3];
      msg._comp = v2 ? frame[6] : frame[4];
      this.emit('message', msg);
    }
  }

  close() {
    this.closing = true;
    clearTimeout(this.retry);
    try {
      if (this.kind === 'tcp') this.sock.destroy(); else this.sock.close();
    } catch (e) { /* already closed */ }
  }
}

module.exports = { Dialect, Link, crc16 };
