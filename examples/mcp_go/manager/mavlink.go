package main

import (
	"encoding/binary"
	"math"
)

type mavMsg struct {
	crcExtra byte
	maxLen   int
	name     string
}

// crcX25 is MAVLink's checksum (CRC-16/MCRF4XX), over the frame after its magic byte and then
// the message's CRC_EXTRA.
func crcX25(data []byte, extra byte) uint16 {
	crc := uint16(0xFFFF)
	step := func(b byte) {
		t := b ^ byte(crc)
		t ^= t << 4
		crc = crc>>8 ^ uint16(t)<<8 ^ uint16(t)<<3 ^ uint16(t)>>4
	}
	for _, b := range data {
		step(b)
	}
	step(extra)
	return crc
}

// validMavFrame: exactly one complete MAVLink v1 or v2 frame with a valid checksum under the
// ardupilotmega dialect (MCP-PAY-6), nothing before or after it.
func validMavFrame(p []byte) bool {
	if len(p) < 8 {
		return false
	}
	switch p[0] {
	case 0xFE: // v1: magic len seq sys comp msgid payload crc(2)
		n := int(p[1])
		if len(p) != n+8 {
			return false
		}
		m, ok := mavMsgs[uint32(p[5])]
		if !ok || n > m.maxLen {
			return false
		}
		return binary.LittleEndian.Uint16(p[6+n:]) == crcX25(p[1:6+n], m.crcExtra)
	case 0xFD: // v2: magic len incompat compat seq sys comp msgid(3) payload crc(2) [signature(13)]
		if len(p) < 12 {
			return false
		}
		n, incompat := int(p[1]), p[2]
		if incompat&^1 != 0 {
			return false
		}
		total := n + 12
		if incompat&1 != 0 {
			total += 13
		}
		if len(p) != total {
			return false
		}
		id := uint32(p[7]) | uint32(p[8])<<8 | uint32(p[9])<<16
		m, ok := mavMsgs[id]
		if !ok || n > m.maxLen {
			return false
		}
		return binary.LittleEndian.Uint16(p[10+n:]) == crcX25(p[1:10+n], m.crcExtra)
	}
	return false
}

// commandLongV1 builds a MAVLink v1 COMMAND_LONG frame (message id 76) from the
// ground station's system 255: the -speed option's MAV_CMD_DO_CHANGE_SPEED for a drone's
// autopilot, carried in a Mav_Passthrough.
func commandLongV1(seq, targetSys byte, command uint16, params [7]float32) []byte {
	const id = 76
	payload := make([]byte, 0, 33)
	for _, f := range params {
		payload = binary.LittleEndian.AppendUint32(payload, math.Float32bits(f))
	}
	payload = binary.LittleEndian.AppendUint16(payload, command)
	payload = append(payload, targetSys, 1, 0) // target_system, target_component, confirmation
	frame := append([]byte{0xFE, byte(len(payload)), seq, 255, 190, id}, payload...)
	return binary.LittleEndian.AppendUint16(frame, crcX25(frame[1:], mavMsgs[id].crcExtra))
}
