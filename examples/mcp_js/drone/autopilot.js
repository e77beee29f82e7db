'use strict';
// The drone's autopilot side (ArduCopter over MAVLink), promise-based: wait for a GPS fix,
// set a mode, arm, take off and wait to altitude, upload a mission, go to a point, RTL.

const MAV_CMD = { NAV_RETURN_TO_LAUNCH: 20, NAV_TAKEOFF: 22, DO_SET_MODE: 176, COMPONENT_ARM_DISARM: 400 };
const COPTER_MODE = { AUTO: 3, GUIDED: 4, RTL: 6 };
const MAV_RESULT_ACCEPTED = 0;

function sleep(ms) { return new Promise((resolve) => setTimeout(resolve, ms)); }

class Autopilot {
  constructor(link, log) {
    this.link = link;
    this.log = log;
    this.target = null;    // { sys, comp } from the autopilot's HEARTBEAT
    this.fixType = 0;
    this.relAlt = 0;       // metres above home
    this.waiters = new Set();
    link.on('message', (m) => this.onMessage(m));
    this.heartbeat = setInterval(() => this.link.send('HEARTBEAT', {
      type: 18 /* MAV_TYPE_ONBOARD_CONTROLLER */, autopilot: 8 /* INVALID */, base_mode: 0,
      custom_mode: 0, system_status: 4, mavlink_version: 3 }), 1000);
    this.link.send('HEARTBEAT', { type: 18, autopilot: 8, system_status: 4, mavlink_version: 3 });
  }

  onMessage(m) {
    if (m._name === 'HEARTBEAT' && m.autopilot !== 8 && !this.target) {
      this.target = { sys: m._sys, comp: m._comp };
      this.log(`autopilot: system ${m._sys} component ${m._comp}`);
      // ask for the streams we watch (ArduPilot streams them anyway to a GCS that spoke)
      for (const stream of [2 /* EXTENDED_STATUS: GPS_RAW_INT */, 6 /* POSITION */]) {
        this.link.send('REQUEST_DATA_STREAM', { target_system: m._sys, target_component: m._comp,
          req_stream_id: stream, req_message_rate: 4, start_stop: 1 });
      }
    }
    if (m._name === 'GPS_RAW_INT') this.fixType = m.fix_type;
    if (m._name === 'GLOBAL_POSITION_INT') this.relAlt = m.relative_alt / 1000;
    for (const w of [...this.waiters]) {
      if (w.match(m)) { this.waiters.delete(w); clearTimeout(w.timer); w.resolve(m); }
    }
  }

  // The next message for which match(m) holds, or null after ms.
  next(match, ms) {
    return new Promise((resolve) => {
      const w = { match, resolve };
      w.timer = setTimeout(() => { this.waiters.delete(w); resolve(null); }, ms);
      this.waiters.add(w);
    });
  }

  async connected() {
    while (!this.target) await this.next((m) => m._name === 'HEARTBEAT' && m.autopilot !== 8, 5000);
  }

  // Mission_Ready only with a 3D fix ("must verify GPS lock ... before sending this message")
  async gpsLock() {
    await this.connected();
    while (this.fixType < 3) await this.next((m) => m._name === 'GPS_RAW_INT' && m.fix_type >= 3, 5000);
  }

  async command(cmd, params, tries = 3) {
    await this.connected();
    for (let i = 0; i < tries; i++) {
      const [p1 = 0, p2 = 0, p3 = 0, p4 = 0, p5 = 0, p6 = 0, p7 = 0] = params;
      this.link.send('COMMAND_LONG', { target_system: this.target.sys, target_component: this.target.comp,
        command: cmd, confirmation: i, param1: p1, param2: p2, param3: p3, param4: p4, param5: p5,
        param6: p6, param7: p7 });
      const ack = await this.next((m) => m._name === 'COMMAND_ACK' && m.command === cmd, 1500);
      if (ack) {
        if (ack.result !== MAV_RESULT_ACCEPTED) throw new Error(`command ${cmd} refused (result ${ack.result})`);
        return;
      }
    }
    throw new Error(`command ${cmd}: no COMMAND_ACK`);
  }

  // a bare arm request, its answer not awaited (the arm_early fault)
  armRequest() {
    this.link.send('COMMAND_LONG', { target_system: this.target.sys, target_component: this.target.comp,
      command: MAV_CMD.COMPONENT_ARM_DISARM, param1: 1 });
  }

  setMode(mode) { return this.command(MAV_CMD.DO_SET_MODE, [1 /* CUSTOM_MODE_ENABLED */, mode]); }

  async takeoff(alt) {
    await this.setMode(COPTER_MODE.GUIDED);
    await this.command(MAV_CMD.COMPONENT_ARM_DISARM, [1]);
    await this.command(MAV_CMD.NAV_TAKEOFF, [0, 0, 0, 0, 0, 0, alt]);
    const deadline = Date.now() + 120000;
    while (this.relAlt < alt * 0.95 && Date.now() < deadline) {
      await this.next((m) => m._name === 'GLOBAL_POSITION_INT', 1000);
    }
    this.log(`take-off: ${this.relAlt.toFixed(1)} m`);
  }

  // MAVLink's mission upload: MISSION_COUNT, then each item as the autopilot asks for it.
  async uploadMission(items) {
    await this.connected();
    const { sys, comp } = this.target;
    let acked = null;
    const onReq = (m) => {
      if ((m._name === 'MISSION_REQUEST' || m._name === 'MISSION_REQUEST_INT') && m.seq < items.length) {
        this.link.send('MISSION_ITEM', { ...items[m.seq], seq: m.seq, target_system: sys, target_component: comp,
          mission_type: 0 });
      } else if (m._name === 'MISSION_ACK') {
        acked = m;
      }
    };
    this.link.on('message', onReq);
    try {
      for (let i = 0; i < 3 && !acked; i++) {
        this.link.send('MISSION_COUNT', { target_system: sys, target_component: comp, count: items.length,
          mission_type: 0 });
        const deadline = Date.now() + 10000;
        while (!acked && Date.now() < deadline) await this.next((m) => m._name === 'MISSION_ACK', 1000);
      }
    } finally {
      this.link.removeListener('message', onReq);
    }
    if (!acked) throw new Error('mission upload: no MISSION_ACK');
    if (acked.type !== 0) throw new Error(`mission upload refused (MAV_MISSION_RESULT ${acked.type})`);
  }

  async flyMission(items) {
    await this.uploadMission(items);
    await this.setMode(COPTER_MODE.AUTO);
  }

  async goTo(item) {
    await this.connected();
    await this.setMode(COPTER_MODE.GUIDED);
    this.link.send('SET_POSITION_TARGET_GLOBAL_INT', { target_system: this.target.sys,
      target_component: this.target.comp, coordinate_frame: 6 /* GLOBAL_RELATIVE_ALT_INT */,
      type_mask: 0x0df8 /* position only */, lat_int: Math.round(item.x * 1e7), lon_int: Math.round(item.y * 1e7),
      alt: item.z });
  }

  // RTL: a mode change by COMMAND_LONG (default) or the SET_MODE message, or the
  // NAV_RETURN_TO_LAUNCH command by COMMAND_LONG or COMMAND_INT
  async rtl(how = 'mode') {
    await this.connected();
    const { sys, comp } = this.target;
    if (how === 'mode') return this.setMode(COPTER_MODE.RTL);
    if (how === 'command') return this.command(MAV_CMD.NAV_RETURN_TO_LAUNCH, []);
    if (how === 'set_mode') {
      this.link.send('SET_MODE', { target_system: sys, base_mode: 1, custom_mode: COPTER_MODE.RTL });
      const hb = await this.next((m) => m._name === 'HEARTBEAT' && m._sys === sys && m.custom_mode === COPTER_MODE.RTL,
        3000);
      if (!hb) throw new Error('SET_MODE RTL: the autopilot did not change mode');
      return undefined;
    }
    this.link.send('COMMAND_INT', { target_system: sys, target_component: comp, frame: 0,
      command: MAV_CMD.NAV_RETURN_TO_LAUNCH });
    const ack = await this.next((m) => m._name === 'COMMAND_ACK' && m.command === MAV_CMD.NAV_RETURN_TO_LAUNCH, 1500);
    if (!ack || ack.result !== MAV_RESULT_ACCEPTED) throw new Error(`COMMAND_INT RTL: ${ack ? ack.result : 'no ACK'}`);
    return undefined;
  }

  forward(frame) { this.link.writeRaw(frame); }

  close() { clearInterval(this.heartbeat); this.link.close(); }
}

module.exports = { Autopilot, sleep };
