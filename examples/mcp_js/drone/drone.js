#!/usr/bin/env node
'use strict';
// An MCP drone application for Node.js: one thread, the event loop. See README.md.
//
//   node drone.js --id 1 --listen 7890 --manager 127.0.0.1:7889 [--mavlink tcp:127.0.0.1:5760
//                 --dialect ardupilotmega.json] [--rto 5] [--retries 1000] [--takeoff-alt 10]

const dgram = require('dgram');
const path = require('path');
const os = require('os');
const { spawnSync } = require('child_process');
const { Dialect, Link } = require('./mavlink');
const { Autopilot } = require('./autopilot');

const PREAMBLE = Buffer.from('NCSU-CM\x01\x01', 'latin1');
const HEADER = 17;
const ITEM = 37;
const ACTION = { MISSION_READY: 0, START_MISSION: 1, END_MISSION: 2, WP_LIST: 3, WP_ON: 4, WP_OFF: 5,
  OBSTACLES_LIST: 6, ACK: 7, MAV_PASSTHROUGH: 8 };
const NAMES = Object.fromEntries(Object.entries(ACTION).map(([k, v]) => [v, k]));
const MANAGER_ID = 0;
// deliberate faults (README): each breaks one rule
const FAULTS = ['no_dedup', 'no_retransmit', 'ack_le', 'ack_broadcast', 'global_dedup', 'any_ack', 'early_ready', 'arm_early',
  'connected'];

function parseArgs(argv) {
  const o = { id: 1, listen: '0.0.0.0:7890', manager: '127.255.255.255:7889', mavlink: null, dialect: null,
    rto: 5, retries: 1000, takeoffAlt: 10, broadcastId: 0xffff, ackWhenDone: false, replyToSource: false,
    exitAfterEnd: false, sendSocket: false, ackSeq: 'next', rtl: 'mode', passthroughQueued: false,
    readyPayload: 'none', firstSeq: null, reannounce: false, verbose: false, managerOnly: false,
    fault: null };
  for (let i = 2; i < argv.length; i++) {
    const a = argv[i];
    const val = () => { if (i + 1 >= argv.length) usage(`${a} needs a value`); return argv[++i]; };
    switch (a) {
      case '--id': o.id = Number(val()); break;
      case '--listen': o.listen = val(); break;
      case '--manager': o.manager = val(); break;
      case '--mavlink': o.mavlink = val(); break;
      case '--dialect': o.dialect = val(); break;
      case '--rto': o.rto = Number(val()); break;
      case '--retries': o.retries = Number(val()); break;
      case '--takeoff-alt': o.takeoffAlt = Number(val()); break;
      case '--broadcast-id': o.broadcastId = Number(val()); break;
      case '--ack-when-done': o.ackWhenDone = true; break;
      case '--reply-to-source': o.replyToSource = true; break;
      case '--exit-after-end': o.exitAfterEnd = true; break;
      case '--send-socket': o.sendSocket = true; break;
      case '--ack-seq': o.ackSeq = val(); break;
      case '--rtl': o.rtl = val(); break;
      case '--passthrough-queued': o.passthroughQueued = true; break;
      case '--ready-payload': o.readyPayload = val(); break;
      case '--first-seq': o.firstSeq = Number(val()); break;
      case '--reannounce': o.reannounce = true; break;
      case '-v': case '--verbose': o.verbose = true; break;
      case '--manager-only': o.managerOnly = true; break;
      case '--fault': o.fault = val(); break;
      case '-h': case '--help': usage(null); break;
      default: usage(`unknown option ${a}`);
    }
  }
  if (!Number.isInteger(o.id) || o.id < 1 || o.id > 0xfffe || o.id === o.broadcastId) usage('--id: 1..65534');
  if (!(o.rto > 0)) usage('--rto: seconds > 0');
  if (!Number.isInteger(o.retries) || o.retries < 0) usage('--retries: an integer >= 0');
  if (!['none', 'id'].includes(o.readyPayload)) usage('--ready-payload: none or id');
  if (o.firstSeq !== null && !(Number.isInteger(o.firstSeq) && o.firstSeq >= 0 && o.firstSeq <= 0xffff)) {
    usage('--first-seq: 0..65535');
  }
  if (!['mode', 'set_mode', 'command', 'command_int'].includes(o.rtl)) usage('--rtl: mode, set_mode, command or command_int');
  if (!['next', 'same', 'echo'].includes(o.ackSeq)) usage('--ack-seq: next, same or echo');
  if (o.fault && !FAULTS.includes(o.fault)) usage(`--fault ${o.fault}`);
  return o;
}

function usage(err) {
  const text = 'usage: drone.js --id N [--listen [HOST:]PORT] [--manager HOST:PORT] [--mavlink URL]\n' +
    '       [--dialect FILE.json] [--rto S] [--retries N] [--takeoff-alt M] [--broadcast-id N]\n' +
    '       [--ack-when-done] [--reply-to-source] [--exit-after-end] [--send-socket]\n' +
    '       [--ack-seq next|same|echo] [--rtl mode|set_mode|command|command_int] [--passthrough-queued]\n' +
    '       [--ready-payload none|id] [--first-seq N] [--reannounce] [-v] [--manager-only]\n' +
    `       [--fault ${FAULTS.join('|')}]`;
  if (err) { process.stderr.write(`drone.js: ${err}\n${text}\n`); process.exit(2); }
  process.stdout.write(`${text}\n`);
  process.exit(0);
}

function hostPort(s, defHost) {
  const i = s.lastIndexOf(':');
  return i < 0 ? { host: defHost, port: Number(s) } : { host: s.slice(0, i) || defHost, port: Number(s.slice(i + 1)) };
}

const opt = parseArgs(process.argv);
const t0 = Date.now();
function log(msg) { process.stderr.write(`[drone ${opt.id} +${((Date.now() - t0) / 1000).toFixed(3)}] ${msg}\n`); }

// --- the MAVLink dialect (Mav_Passthrough frames are checked by it) and the autopilot -----
function loadDialect() {
  let file = opt.dialect;
  if (!file) {  // no file given: generate it from pymavlink's XML
    file = path.join(os.tmpdir(), `mcp-js-drone-dialect-${process.pid}.json`);
    const r = spawnSync(process.env.PYTHON || 'python3', [path.join(__dirname, 'gen_dialect.py'), file],
      { stdio: 'inherit' });
    if (r.status !== 0) { log('cannot generate the MAVLink dialect (pass --dialect)'); process.exit(2); }
  }
  return new Dialect(file);
}
const dialect = loadDialect();
let autopilot = null;
if (opt.mavlink) {
  const link = new Link(opt.mavlink, dialect);
  link.on('error', (e) => log(`autopilot link: ${e.message}`));
  autopilot = new Autopilot(link, log);
}

// --- MCP ------------------------------------------------------------------------------------
const manager = hostPort(opt.manager, '127.0.0.1');
const listen = hostPort(opt.listen, '0.0.0.0');
const sock = dgram.createSocket('udp4');
// "an arbitrary initial sequence number"
let nextSeq = opt.firstSeq === null ? Math.floor(Math.random() * 0x10000) : opt.firstSeq;
const lastDelivered = new Map();  // src -> { seq, done }: the duplicate table (per source)
let outstanding = null;           // our one unicast awaiting its ACK (stop-and-wait)

function takeSeq() { const s = nextSeq; nextSeq = (nextSeq + 1) & 0xffff; return s; }

function datagram(dst, seq, action, payload = Buffer.alloc(0)) {
  const buf = Buffer.alloc(HEADER + payload.length);
  PREAMBLE.copy(buf, 0);
  buf.writeUInt16BE(dst, 9);
  buf.writeUInt16BE(opt.id, 11);
  buf.writeUInt16BE(seq, 13);
  buf.writeUInt16BE(action, 15);
  payload.copy(buf, HEADER);
  return buf;
}

// one socket for both ways, or (--send-socket) a socket of its own to send from, on an
// ephemeral port
const out = opt.sendSocket ? dgram.createSocket('udp4') : sock;
if (out !== sock) out.bind(0, () => out.setBroadcast(true));
function send(buf, to = manager) {
  if (opt.fault === 'connected') out.send(buf); else out.send(buf, to.port, to.host);
}

// Send a unicast and retransmit it every --rto until its ACK comes or --retries are spent.
function sendUnicast(dst, action, payload) {
  return new Promise((resolve, reject) => {
    const seq = takeSeq();
    const buf = datagram(dst, seq, action, payload);
    let copies = 0;
    const fire = () => {
      if (copies > opt.retries) {
        outstanding = null;
        reject(new Error(`${NAMES[action]} seq ${seq}: no ACK after ${copies} copies`));
        return;
      }
      send(buf);
      copies++;
      if (opt.fault !== 'no_retransmit') outstanding.timer = setTimeout(fire, opt.rto * 1000);
    };
    outstanding = { dst, seq, action, resolve, timer: null };
    fire();
  });
}

function onAck(src, acked) {
  // MCP-RTX-2: only the destination's ACK naming our seq ends the retransmission
  if (outstanding && ((src === outstanding.dst && acked === outstanding.seq) || opt.fault === 'any_ack')) {
    clearTimeout(outstanding.timer);
    const o = outstanding;
    outstanding = null;
    o.resolve();
  }
}

function sendAck(src, seq, rinfo) {
  const payload = Buffer.alloc(2);
  if (opt.fault === 'ack_le') payload.writeUInt16LE(seq, 0); else payload.writeUInt16BE(seq, 0);
  // D-5: an ACK's own number is not specified: the next one (the sample's "during every send"),
  // the sender's current one without taking it (same), or the acknowledged one (echo)
  const own = opt.ackSeq === 'next' ? takeSeq() : opt.ackSeq === 'same' ? nextSeq : seq;
  send(datagram(src, own, ACTION.ACK, payload), opt.replyToSource ? { host: rinfo.address, port: rinfo.port } : manager);
}

function decodeItem(buf, off) {
  return { param1: buf.readFloatLE(off), param2: buf.readFloatLE(off + 4), param3: buf.readFloatLE(off + 8),
    param4: buf.readFloatLE(off + 12), x: buf.readFloatLE(off + 16), y: buf.readFloatLE(off + 20),
    z: buf.readFloatLE(off + 24), seq: buf.readUInt16LE(off + 28), command: buf.readUInt16LE(off + 30),
    target_system: buf[off + 32], target_component: buf[off + 33], frame: buf[off + 34],
    current: buf[off + 35], autocontinue: buf[off + 36] };
}

function decodeList(payload) {
  const n = payload.readUInt16BE(0);
  const items = [];
  for (let i = 0; i < n; i++) items.push(decodeItem(payload, 2 + ITEM * i));
  return items;
}

// D-4: a payload that does not fit its action code is malformed (no ACK, no delivery)
function fits(action, payload, src) {
  switch (action) {
    case ACTION.MISSION_READY: return payload.length === 0 || (payload.length === 2 && payload.readUInt16BE(0) === src);
    case ACTION.START_MISSION: case ACTION.END_MISSION: case ACTION.WP_OFF: return payload.length === 0;
    case ACTION.WP_LIST: case ACTION.OBSTACLES_LIST:
      return payload.length >= 2 && payload.length === 2 + ITEM * payload.readUInt16BE(0);
    case ACTION.WP_ON: return payload.length === ITEM;
    case ACTION.ACK: return payload.length === 2;
    case ACTION.MAV_PASSTHROUGH: return mavFrameOk(payload);
    default: return false;
  }
}

function mavFrameOk(payload) { return dialect.isOneFrame(payload); }

// The application: its autopilot work runs one job at a time, in the order the commands came.
let work = Promise.resolve();
function queue(name, job) {
  const done = work.then(job).catch((e) => log(`${name}: ${e.message}`));
  work = done;
  return done;
}

function deliver(src, action, payload) {
  const name = NAMES[action];
  switch (action) {
    case ACTION.START_MISSION:
      log(`Start_Mission from ${src}: arm and take off to ${opt.takeoffAlt} m`);
      return queue(name, () => autopilot && autopilot.takeoff(opt.takeoffAlt));
    case ACTION.END_MISSION:
      log(`End_Mission from ${src}: RTL once pending actions are done`);
      return queue(name, async () => {
        if (autopilot) await autopilot.rtl(opt.rtl);
        if (opt.exitAfterEnd) setImmediate(() => shutdown('mission over'));
      });
    case ACTION.WP_LIST: {
      const items = decodeList(payload);
      log(`WP_List from ${src}: ${items.length} waypoints`);
      return queue(name, () => autopilot && items.length && autopilot.flyMission(items));
    }
    case ACTION.WP_ON: {
      const item = decodeItem(payload, 0);
      log(`WP_On from ${src}: ${item.x}, ${item.y}, ${item.z} m`);
      return queue(name, () => autopilot && autopilot.goTo(item));
    }
    case ACTION.WP_OFF:
      log(`WP_Off from ${src}: the active waypoint is inactive`);
      return Promise.resolve();
    case ACTION.OBSTACLES_LIST:
      log(`Obstacles_List from ${src}: ${decodeList(payload).length} obstacles`);
      return Promise.resolve();
    case ACTION.MAV_PASSTHROUGH:
      log(`Mav_Passthrough from ${src}: ${payload.length} bytes${autopilot ? ' forwarded' : ''}`);
      // exactly once per delivery (MCP-PAY-8): at once, or (--passthrough-queued) in the
      // commands' order, after the autopilot jobs before it
      if (opt.passthroughQueued) return queue(name, () => autopilot && autopilot.forward(payload));
      if (autopilot) autopilot.forward(payload);
      return Promise.resolve();
    default:  // Mission_Ready: a drone has no use for one
      log(`${name} from ${src}: ignored`);
      return Promise.resolve();
  }
}

sock.on('message', (buf, rinfo) => {
  if (opt.verbose) log(`<- ${rinfo.address}:${rinfo.port} ${buf.length} bytes ${buf.subarray(0, 17).toString('hex')}`);
  if (buf.length < HEADER || !buf.subarray(0, 9).equals(PREAMBLE)) return;  // MCP-ROB-1/2
  const dst = buf.readUInt16BE(9);
  const src = buf.readUInt16BE(11);
  const seq = buf.readUInt16BE(13);
  const action = buf.readUInt16BE(15);
  if (action > ACTION.MAV_PASSTHROUGH) return;                                // MCP-ROB-3
  const payload = buf.subarray(HEADER);
  if (!fits(action, payload, src)) return;                                    // MCP-ROB-4, D-4
  const unicast = dst === opt.id;
  if (!unicast && dst !== opt.broadcastId) return;                            // MCP-ACK-5
  // D-10: every command comes from the manager, ID 0: --manager-only ignores any other src
  if (opt.managerOnly && src !== MANAGER_ID) return;
  if (action === ACTION.ACK) {                                                // MCP-ACK-6
    if (unicast) onAck(src, payload.readUInt16BE(0));
    return;
  }
  // duplicate discard, per source: the same seq as the last delivered from that src (MCP-DUP-*)
  const key = opt.fault === 'global_dedup' ? 'any' : src;
  const last = lastDelivered.get(key);
  let done;
  if (last && last.seq === seq && opt.fault !== 'no_dedup') {
    done = last.done;
  } else {
    done = deliver(src, action, payload);
    lastDelivered.set(key, { seq, done });
  }
  if (!unicast && opt.fault !== 'ack_broadcast') return;                      // MCP-ACK-4
  if (opt.ackWhenDone) done.then(() => sendAck(src, seq, rinfo)); else sendAck(src, seq, rinfo);
});

sock.on('error', (e) => { log(`socket: ${e.message}`); process.exit(2); });

function shutdown(sig) {
  log(`${sig}: stopping`);
  sock.close();
  if (out !== sock) out.close();
  if (autopilot) autopilot.close();
  process.exit(0);
}
process.on('SIGTERM', () => shutdown('SIGTERM'));
process.on('SIGINT', () => shutdown('SIGINT'));

sock.bind(listen.port, listen.host, async () => {
  sock.setBroadcast(true);
  // the connected fault: a socket connect()ed to the manager takes datagrams from that address only
  if (opt.fault === 'connected') await new Promise((resolve) => sock.connect(manager.port, manager.host, resolve));
  log(`listening on ${listen.host}:${listen.port}, manager ${manager.host}:${manager.port}, rto ${opt.rto} s`);
  // Mission_Ready only once ready to fly: the autopilot's GPS lock first (MCP-BLK-5). The
  // autopilot queue holds any command that comes meanwhile behind this.
  const ready = queue('ready', async () => {
    if (!autopilot) return;
    if (opt.fault === 'arm_early') {
      await autopilot.connected();
      autopilot.armRequest();
    }
    if (opt.fault !== 'early_ready') await autopilot.gpsLock();
  });
  await ready;
  log('ready: Mission_Ready');
  // D-3: the sample sends no payload; the manager's handler reads the drone's ID from it
  const payload = Buffer.alloc(opt.readyPayload === 'id' ? 2 : 0);
  if (payload.length) payload.writeUInt16BE(opt.id, 0);
  for (;;) {
    try {
      await sendUnicast(MANAGER_ID, ACTION.MISSION_READY, payload);
      log('Mission_Ready ACKed');
      return;
    } catch (e) {
      if (!opt.reannounce) {
        log(`${e.message}: giving up`);
        sock.close();
        if (autopilot) autopilot.close();
        process.exit(1);
      }
      log(`${e.message}: announcing again`);  // --reannounce: a new Mission_Ready, a new seq
    }
  }
});
