package main

import (
	"bytes"
	"testing"
)

// The seed 001 heartbeat of docs/guide/vehicle.md: a MAVLink 1 HEARTBEAT with a valid checksum.
var heartbeat = []byte{0xFE, 0x09, 0x00, 0xFF, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x06, 0x03, 0xC0, 0x04, 0x03, 0xF5, 0xC0}

func TestMavFrames(t *testing.T) {
	if !validMavFrame(heartbeat) {
		t.Fatal("the documented heartbeat is not a valid frame")
	}
	bad := bytes.Clone(heartbeat)
	bad[len(bad)-1] ^= 1
	if validMavFrame(bad) || validMavFrame(append(bytes.Clone(heartbeat), 0)) {
		t.Fatal("a wrong checksum or a trailing byte passed")
	}
	if f := commandLongV1(0, 1, 178, [7]float32{1, 5, -1}); !validMavFrame(f) || len(f) != 33+8 {
		t.Fatalf("COMMAND_LONG %x", f)
	}
}

func TestHeaderAndPayloads(t *testing.T) {
	b := encode(header{dst: 1, src: 0, seq: 0xABCD, act: actACK}, seqPayload(0x1234))
	want := []byte("NCSU-CM\x01\x01\x00\x01\x00\x00\xAB\xCD\x00\x07\x12\x34")
	if !bytes.Equal(b, want) {
		t.Fatalf("%x", b)
	}
	for _, c := range []struct {
		b   []byte
		err error
	}{
		{b[:16], errShort},
		{append([]byte("NCSU-CN\x01\x01"), b[9:]...), errPreamble},
		{encode(header{act: 9}, nil), errAction},
		{encode(header{act: actStartMission}, []byte{0}), errPayload},
		{encode(header{src: 2, act: actMissionReady}, []byte{0, 3}), errPayload}, // D-3: not its src
		{encode(header{act: actWPList}, append([]byte{0, 1}, make([]byte, 36)...)), errPayload},
		{encode(header{src: 2, act: actMissionReady}, []byte{0, 2}), nil},
		{encode(header{act: actWPOn}, make([]byte, itemLen)), nil},
		{encode(header{act: actMavPassthrough}, heartbeat), nil},
	} {
		if _, _, err := parse(c.b); err != c.err {
			t.Errorf("%x: %v, want %v", c.b, err, c.err)
		}
	}
}

func TestWaypointItem(t *testing.T) {
	it := item{x: 35.77, y: -78.67, z: 3, seq: 2, command: 16, frame: 3, current: 1, autocon: 1}
	b := it.encode()
	if len(b) != itemLen || b[28] != 2 || b[30] != 16 || b[34] != 3 || b[35] != 1 || b[36] != 1 {
		t.Fatalf("%x", b)
	}
	if p := listPayload([]item{it, it}); len(p) != 2+2*itemLen || p[0] != 0 || p[1] != 2 {
		t.Fatalf("%x", p[:2])
	}
}
