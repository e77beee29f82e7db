package main

import (
	"bufio"
	"encoding/binary"
	"fmt"
	"math"
	"os"
	"strconv"
	"strings"
)

// item is one waypoint of a QGC WPL 110 file, sent as a MAVLink v1 MISSION_ITEM payload:
// '<fffffffHHBBBBB', 37 bytes (docs/spec.md "Mission item", E-1; x = latitude, E-2).
type item struct {
	params                  [4]float32
	x, y, z                 float32
	seq, command            uint16
	frame, current, autocon uint8
}

// encode packs the item little-endian as MAVLink does; target_system and target_component
// are 0 (the file names no target; MAVLink's 0 is "all").
func (it item) encode() []byte {
	b := make([]byte, 0, itemLen)
	for _, f := range [...]float32{it.params[0], it.params[1], it.params[2], it.params[3], it.x, it.y, it.z} {
		b = binary.LittleEndian.AppendUint32(b, math.Float32bits(f))
	}
	b = binary.LittleEndian.AppendUint16(b, it.seq)
	b = binary.LittleEndian.AppendUint16(b, it.command)
	return append(b, 0, 0, it.frame, it.current, it.autocon)
}

// readWaypoints reads a QGC WPL 110 file: a "QGC WPL 110" line, then one line per item,
// INDEX CURRENT FRAME COMMAND PARAM1..4 X Y Z AUTOCONTINUE, separated by tabs (or spaces).
func readWaypoints(path string) ([]item, error) {
	f, err := os.Open(path)
	if err != nil {
		return nil, err
	}
	defer f.Close()
	sc := bufio.NewScanner(f)
	var items []item
	line := 0
	for sc.Scan() {
		line++
		text := strings.TrimSpace(sc.Text())
		if line == 1 {
			if !strings.HasPrefix(text, "QGC WPL 110") {
				return nil, fmt.Errorf("%s:1: not a QGC WPL 110 file", path)
			}
			continue
		}
		if text == "" {
			continue
		}
		fields := strings.Fields(text)
		if len(fields) != 12 {
			return nil, fmt.Errorf("%s:%d: %d fields, expected 12", path, line, len(fields))
		}
		var ints [4]uint64
		for i, bits := range [...]int{16, 8, 8, 16} { // index, current, frame, command
			if ints[i], err = strconv.ParseUint(fields[i], 10, bits); err != nil {
				return nil, fmt.Errorf("%s:%d: %v", path, line, err)
			}
		}
		var fl [7]float32
		for i := range fl {
			v, err := strconv.ParseFloat(fields[4+i], 32)
			if err != nil {
				return nil, fmt.Errorf("%s:%d: %v", path, line, err)
			}
			fl[i] = float32(v)
		}
		auto, err := strconv.ParseUint(fields[11], 10, 8)
		if err != nil {
			return nil, fmt.Errorf("%s:%d: %v", path, line, err)
		}
		items = append(items, item{
			params: [4]float32{fl[0], fl[1], fl[2], fl[3]}, x: fl[4], y: fl[5], z: fl[6],
			seq: uint16(ints[0]), current: uint8(ints[1]), frame: uint8(ints[2]), command: uint16(ints[3]),
			autocon: uint8(auto),
		})
	}
	if err := sc.Err(); err != nil {
		return nil, err
	}
	if line == 0 {
		return nil, fmt.Errorf("%s: empty file", path)
	}
	if headerLen+2+itemLen*len(items) > maxDatagram {
		return nil, fmt.Errorf("%s: %d items do not fit one datagram", path, len(items))
	}
	return items, nil
}

// listPayload is a WP_List or Obstacles_List payload: a u16 big-endian count (D-2), then the
// items (MCP-PAY-3).
func listPayload(items []item) []byte {
	b := binary.BigEndian.AppendUint16(nil, uint16(len(items)))
	for _, it := range items {
		b = append(b, it.encode()...)
	}
	return b
}
