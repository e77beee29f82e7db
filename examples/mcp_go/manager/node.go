package main

import (
	"context"
	"encoding/binary"
	"errors"
	"fmt"
	"log"
	"net"
	"sync"
	"time"
)

// errGaveUp: a unicast message's retry limit was reached without its ACK.
var errGaveUp = errors.New("retry limit reached without an ACK")

// node is the manager's MCP endpoint: one UDP socket, a reader goroutine that ACKs and
// routes what arrives, and the reliable unicast send the drones' goroutines call.
type node struct {
	conn        *net.UDPConn // receives (and sends, unless out is set)
	out         *net.UDPConn // -separate-send-socket: sends from a port of its own
	sendTo      *net.UDPAddr // every datagram goes here: "local subnet IP broadcasts" (MCP-TRN-1)
	broadcastID uint16
	rto         time.Duration
	retries     int
	verbose     bool
	// ackKeepsSeq (-ack-seq keep): an ACK carries the number last taken without taking a new
	// one (D-5: "Whether an ACK takes a sequence number of its own is not specified").
	ackKeepsSeq bool
	// replyToSource (-reply-to-source): an ACK goes to the address the message came from.
	replyToSource bool
	// gaveUp, if set, is called when a retry limit is reached, before the token is released
	// (-exit-on-give-up: no other goroutine sends a new message after the give-up).
	gaveUp func()

	// sendMu makes taking the next number and sending one step, so the numbers leave in order
	// whichever goroutine sends (MCP-SEQ-1); every new message takes one, ACKs too (D-5).
	sendMu sync.Mutex
	seq    uint16

	// token is held by the one unicast message awaiting its ACK: the whole node sends no new
	// unicast other than an ACK meanwhile (MCP-BLK-1, "If these are not specified, the call
	// blocks"). The pipeline build (fault_pipeline) holds one per drone instead.
	token chan struct{}

	acks  map[uint16]chan uint16 // drone ID -> the numbers its ACKs carry (routed by src)
	ready chan uint16            // Mission_Ready delivered (not a duplicate), by drone ID
}

func newNode(conn *net.UDPConn, sendTo *net.UDPAddr, drones []uint16, initialSeq uint16) *node {
	n := &node{conn: conn, sendTo: sendTo, token: make(chan struct{}, 1),
		acks: make(map[uint16]chan uint16), ready: make(chan uint16, 64)}
	n.seq = initialSeq - 1
	for _, d := range drones {
		n.acks[d] = make(chan uint16, 64)
	}
	return n
}

// send sends a new message under the next sequence number and returns its bytes, for the
// retransmissions to repeat exactly (MCP-SEQ-2), with the number it took.
func (n *node) send(h header, payload []byte) (uint16, []byte) {
	return n.sendVia(h, payload, n.sendTo)
}

func (n *node) sendVia(h header, payload []byte, to *net.UDPAddr) (uint16, []byte) {
	n.sendMu.Lock()
	defer n.sendMu.Unlock()
	if h.act != actACK || !n.ackKeepsSeq {
		n.seq++
	}
	h.seq = n.seq
	b := encode(h, payload)
	n.writeTo(h, b, to)
	return h.seq, b
}

func (n *node) write(h header, b []byte) { n.writeTo(h, b, n.sendTo) }

func (n *node) writeTo(h header, b []byte, to *net.UDPAddr) {
	conn := n.conn
	if n.out != nil {
		conn = n.out
	}
	if _, err := conn.WriteToUDP(b, to); err != nil {
		log.Printf("send %v to %d: %v", h.act, h.dst, err)
	} else if n.verbose {
		log.Printf("-> %v dst=%d seq=%d len=%d", h.act, h.dst, h.seq, len(b))
	}
}

// read is the reader goroutine: it ends when the socket is closed.
func (n *node) read() {
	buf := make([]byte, 65536)
	last := map[uint16]uint16{} // src -> the seq last delivered from it (MCP-DUP-1)
	for {
		size, from, err := n.conn.ReadFromUDP(buf)
		if err != nil {
			if errors.Is(err, net.ErrClosed) {
				return
			}
			log.Printf("receive: %v", err)
			continue
		}
		h, p, err := parse(buf[:size])
		if err != nil {
			if n.verbose {
				log.Printf("<- %d bytes from %v discarded: %v", size, from, err)
			}
			continue
		}
		if n.verbose {
			log.Printf("<- %v dst=%d src=%d seq=%d from %v", h.act, h.dst, h.src, h.seq, from)
		}
		if h.dst != managerID {
			continue // a broadcast is not ACKed (MCP-ACK-4); another ID's message neither (MCP-ACK-5)
		}
		if h.act == actACK { // never ACK an ACK (MCP-ACK-6); hand it to the drone's sender
			if ch, ok := n.acks[h.src]; ok {
				select {
				case ch <- binary.BigEndian.Uint16(p):
				default: // nobody is waiting and the buffer is full: an old ACK
				}
			}
			continue
		}
		// every well-formed unicast to ID 0, every copy: ACK to its src (MCP-ACK-1/2/3)
		to := n.sendTo
		if n.replyToSource {
			to = from
		}
		n.sendVia(header{dst: h.src, src: managerID, act: actACK}, seqPayload(h.seq), to)
		if prev, ok := last[h.src]; ok && prev == h.seq {
			continue // a duplicate: ACKed again, not delivered again (MCP-DUP-1)
		}
		last[h.src] = h.seq
		if h.act == actMissionReady {
			select {
			case n.ready <- h.src:
			default:
			}
		} else if n.verbose {
			log.Printf("%v from %d: not a message a manager acts on", h.act, h.src)
		}
	}
}

// acquire takes the node's send token (the pipeline build: none).
func (n *node) acquire(ctx context.Context) error {
	if faultPipeline {
		return nil
	}
	select {
	case n.token <- struct{}{}:
		return nil
	case <-ctx.Done():
		return ctx.Err()
	}
}

func (n *node) release() {
	if !faultPipeline {
		<-n.token
	}
}

// unicast sends one message to a drone and blocks until the drone ACKs it: the first copy,
// then a copy every rto, up to 1 + retries copies (MCP-RTX-1, MCP-SEQ-2: every copy the same
// bytes). Only an ACK from that drone naming this number ends it (MCP-RTX-2).
func (n *node) unicast(ctx context.Context, drone uint16, act action, payload []byte) error {
	if err := n.acquire(ctx); err != nil {
		return err
	}
	defer n.release()
	acks := n.acks[drone]
	for len(acks) > 0 { // ACKs of earlier messages
		<-acks
	}
	h := header{dst: drone, src: managerID, act: act}
	var b []byte
	wait := n.rto
	copies := n.retries + 1
	if faultNoRetransmit { // one copy, the same total wait
		wait *= time.Duration(copies)
		copies = 1
	}
	for c := 0; c < copies; c++ {
		if b == nil {
			h.seq, b = n.send(h, payload)
		} else {
			n.write(h, b)
		}
		timer := time.NewTimer(wait)
	waiting:
		for {
			select {
			case <-ctx.Done():
				timer.Stop()
				return ctx.Err()
			case acked := <-acks:
				if acked == h.seq {
					timer.Stop()
					return nil
				}
			case <-timer.C:
				break waiting
			}
		}
	}
	if n.gaveUp != nil {
		n.gaveUp()
	}
	return fmt.Errorf("%v seq %d to drone %d: %w", act, h.seq, drone, errGaveUp)
}

// broadcast sends a message once to every drone (D-11): not ACKed (MCP-ACK-4), not
// retransmitted (MCP-RTX-4). It waits for the token so that no unicast is outstanding.
func (n *node) broadcast(ctx context.Context, act action, payload []byte) error {
	if err := n.acquire(ctx); err != nil {
		return err
	}
	defer n.release()
	n.send(header{dst: n.broadcastID, src: managerID, act: act}, payload)
	return nil
}
