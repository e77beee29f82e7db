package main

import (
	"encoding/binary"
	"errors"
	"fmt"
)

// The MCP header (docs/spec.md, "Header"): 17 bytes, struct "!7s2B4H", network byte order.
const (
	headerLen   = 17
	itemLen     = 37    // a mission item: MAVLink v1 MISSION_ITEM payload (E-1)
	managerID   = 0     // "By convention, the Mission Manager always has the ID 0." (MCP-HDR-4)
	maxDatagram = 65507 // the largest UDP payload over IPv4 (MCP-ROB-6)
)

// preamble: "NCSU-CM", 0x01, 0x01 (MCP-HDR-1).
var preamble = [9]byte{'N', 'C', 'S', 'U', '-', 'C', 'M', 1, 1}

type action uint16

// Action codes 0-8 on the wire; 9 ("Any") is an API filter and never sent (MCP-HDR-3).
const (
	actMissionReady action = iota
	actStartMission
	actEndMission
	actWPList
	actWPOn
	actWPOff
	actObstaclesList
	actACK
	actMavPassthrough
)

var actionNames = [...]string{"Mission_Ready", "Start_Mission", "End_Mission", "WP_List", "WP_On",
	"WP_Off", "Obstacles_List", "ACK", "Mav_Passthrough"}

func (a action) String() string {
	if int(a) < len(actionNames) {
		return actionNames[a]
	}
	return fmt.Sprintf("action(%d)", uint16(a))
}

type header struct {
	dst, src, seq uint16
	act           action
}

// encode builds one datagram: the header in network byte order, then the payload (MCP-HDR-2).
func encode(h header, payload []byte) []byte {
	b := make([]byte, headerLen+len(payload))
	copy(b, preamble[:])
	binary.BigEndian.PutUint16(b[9:], h.dst)
	binary.BigEndian.PutUint16(b[11:], h.src)
	binary.BigEndian.PutUint16(b[13:], h.seq)
	binary.BigEndian.PutUint16(b[15:], uint16(h.act))
	copy(b[headerLen:], payload)
	return b
}

var (
	errShort    = errors.New("shorter than 17 bytes (MCP-ROB-1)")
	errPreamble = errors.New("not the preamble (MCP-ROB-2)")
	errAction   = errors.New("action code above 8 (MCP-ROB-3)")
	errPayload  = errors.New("payload does not fit its action code (MCP-ROB-4, D-4)")
)

// parse checks a received datagram. A non-nil error means: discard it silently, no ACK and
// no delivery (MCP-ROB-1..4, D-4).
func parse(b []byte) (header, []byte, error) {
	var h header
	if len(b) < headerLen {
		return h, nil, errShort
	}
	if [9]byte(b[:9]) != preamble {
		return h, nil, errPreamble
	}
	h.dst = binary.BigEndian.Uint16(b[9:])
	h.src = binary.BigEndian.Uint16(b[11:])
	h.seq = binary.BigEndian.Uint16(b[13:])
	h.act = action(binary.BigEndian.Uint16(b[15:]))
	if h.act > actMavPassthrough {
		return h, nil, errAction
	}
	p := b[headerLen:]
	if !payloadFits(h, p) {
		return h, nil, errPayload
	}
	return h, p, nil
}

// payloadFits is docs/spec.md's "Payload layouts" table, with D-2 (big-endian counts and ACK
// numbers) and D-3 (Mission_Ready: empty, or the sender's own ID).
func payloadFits(h header, p []byte) bool {
	switch h.act {
	case actMissionReady:
		return len(p) == 0 || (len(p) == 2 && binary.BigEndian.Uint16(p) == h.src)
	case actStartMission, actEndMission, actWPOff:
		return len(p) == 0
	case actWPList, actObstaclesList:
		return len(p) >= 2 && len(p) == 2+itemLen*int(binary.BigEndian.Uint16(p))
	case actWPOn:
		return len(p) == itemLen
	case actACK:
		return len(p) == 2
	case actMavPassthrough:
		return validMavFrame(p)
	}
	return false
}

// seqPayload is an ACK's payload: the acknowledged sequence number, big-endian (MCP-ACK-2, D-2).
func seqPayload(seq uint16) []byte {
	return binary.BigEndian.AppendUint16(nil, seq)
}
