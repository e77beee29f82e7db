// Command manager is a CentMesh MCP Mission Manager written from the protocol's documents
// (docs/spec.md, spec/mcp.yaml, docs/guide/manager.md): it waits for every drone's
// Mission_Ready, starts each drone's mission, runs challenge 1, 2 or 3 and ends the missions.
//
// One goroutine per drone drives that drone's mission as sequential code; a reader goroutine
// ACKs every unicast addressed to ID 0 and routes ACKs to the drone that sent them. Unicast
// sends are stop-and-wait across the whole node (MCP-BLK-1).
package main

import (
	"context"
	"errors"
	"flag"
	"fmt"
	"log"
	"math/rand/v2"
	"net"
	"os"
	"os/signal"
	"strconv"
	"strings"
	"sync"
	"syscall"
	"time"
)

type config struct {
	bind, sendTo          string
	drones                []uint16
	challenge             int
	waypoints, obstacles  string
	rto, hold, linger     time.Duration
	retries               int
	broadcastID           uint16
	broadcastLists        bool
	speed                 float64
	initialSeq            int
	exitOnGiveUp, verbose bool
	ackKeepsSeq           bool
	replyToSource         bool
	separateSend          bool
}

func parseDrones(s string) ([]uint16, error) {
	var ids []uint16
	seen := map[uint16]bool{}
	for _, f := range strings.Split(s, ",") {
		v, err := strconv.ParseUint(strings.TrimSpace(f), 10, 16)
		if err != nil || v == managerID || v == 0xFFFF {
			return nil, fmt.Errorf("-drones: %q is not a drone ID (1-65534)", f)
		}
		if !seen[uint16(v)] {
			seen[uint16(v)] = true
			ids = append(ids, uint16(v))
		}
	}
	return ids, nil
}

func seconds(fs *flag.FlagSet, name string, def float64, usage string) *float64 {
	return fs.Float64(name, def, usage+" (seconds)")
}

func parseFlags(args []string) (config, error) {
	var c config
	fs := flag.NewFlagSet("manager", flag.ContinueOnError)
	fs.StringVar(&c.bind, "bind", "0.0.0.0:7889", "HOST:PORT the manager receives on (MCP-TRN-1: port 7889)")
	fs.StringVar(&c.sendTo, "send-to", "127.255.255.255:7890", "HOST:PORT every datagram goes to (the drones' broadcast address and port)")
	drones := fs.String("drones", "1", "the mission's drone IDs, comma-separated")
	fs.IntVar(&c.challenge, "challenge", 1, "1 waypoint list, 2 active waypoints, 3 obstacles")
	fs.StringVar(&c.waypoints, "waypoints", "", "the mission's QGC WPL 110 waypoint file")
	fs.StringVar(&c.obstacles, "obstacles", "", "challenge 3: the obstacles' QGC WPL 110 file")
	rto := seconds(fs, "rto", 5, "retransmission timeout of a unicast message ('timeout = 5')")
	fs.IntVar(&c.retries, "retries", 1000, "retransmissions of a unicast message before giving up ('num_of_retries=1000')")
	bid := fs.Uint("broadcast-id", 0xFFFF, "the broadcast MCP ID (D-1)")
	fs.BoolVar(&c.broadcastLists, "broadcast-lists", false, "send the challenge's messages once, broadcast, after every Start_Mission is ACKed (D-11)")
	fs.Float64Var(&c.speed, "speed", 0, "if set, send each drone a Mav_Passthrough DO_CHANGE_SPEED (m/s) after its Start_Mission")
	hold := seconds(fs, "hold", 0, "challenge 2: how long each waypoint stays active")
	linger := seconds(fs, "linger", 0, "after the missions, keep ACKing this long")
	fs.IntVar(&c.initialSeq, "initial-seq", -1, "first sequence number (default: random, MCP-SEQ-4)")
	fs.BoolVar(&c.exitOnGiveUp, "exit-on-give-up", false, "end the whole manager (exit 1) when a drone's retry limit is reached, instead of abandoning that drone's mission")
	ackSeq := fs.String("ack-seq", "next", "an ACK's own number: next (it takes one, as every send does) or keep (the number last taken; D-5)")
	fs.BoolVar(&c.replyToSource, "reply-to-source", false, "send each ACK to the address its message came from, not to -send-to")
	fs.BoolVar(&c.separateSend, "separate-send-socket", false, "send from a second socket (an ephemeral port on the -bind address), receive on -bind")
	fs.BoolVar(&c.verbose, "v", false, "log every datagram")
	if err := fs.Parse(args); err != nil {
		return c, err
	}
	if fs.NArg() > 0 {
		return c, fmt.Errorf("unexpected arguments %q", fs.Args())
	}
	if *ackSeq != "next" && *ackSeq != "keep" {
		return c, fmt.Errorf("-ack-seq %q: next or keep", *ackSeq)
	}
	c.ackKeepsSeq = *ackSeq == "keep"
	var err error
	if c.drones, err = parseDrones(*drones); err != nil {
		return c, err
	}
	if c.challenge < 1 || c.challenge > 3 {
		return c, fmt.Errorf("-challenge %d: 1, 2 or 3", c.challenge)
	}
	if c.waypoints == "" || (c.challenge == 3 && c.obstacles == "") {
		return c, errors.New("-waypoints (and, for challenge 3, -obstacles) required")
	}
	if *rto <= 0 || c.retries < 0 || *bid > 0xFFFF || c.initialSeq > 0xFFFF || *hold < 0 || *linger < 0 {
		return c, errors.New("-rto > 0, -retries >= 0, -broadcast-id and -initial-seq < 65536")
	}
	c.rto = time.Duration(*rto * float64(time.Second))
	c.hold = time.Duration(*hold * float64(time.Second))
	c.linger = time.Duration(*linger * float64(time.Second))
	c.broadcastID = uint16(*bid)
	return c, nil
}

// commands is one drone's challenge, in order (docs/reference/glossary.md "Challenge").
type command struct {
	act     action
	payload []byte
}

func challengeCommands(c config, wps, obs []item) []command {
	switch c.challenge {
	case 1: // the mission's waypoints as one WP_List (MCP-FLOW-4)
		return []command{{actWPList, listPayload(wps)}}
	case 2: // each waypoint active, then inactive: WP_On, WP_Off (MCP-FLOW-5)
		var cmds []command
		for _, it := range wps {
			cmds = append(cmds, command{actWPOn, it.encode()}, command{actWPOff, nil})
		}
		return cmds
	default: // the obstacles as one Obstacles_List (MCP-FLOW-6), then the route as a WP_List
		return []command{{actObstaclesList, listPayload(obs)}, {actWPList, listPayload(wps)}}
	}
}

// manager is the mission: the node and what each drone is sent.
type manager struct {
	cfg      config
	n        *node
	cmds     []command
	allReady chan struct{} // closed once every drone sent Mission_Ready (MCP-BLK-2)
	started  sync.WaitGroup
	listed   chan struct{} // -broadcast-lists: closed once the challenge was broadcast
}

// waitReady collects Mission_Ready from every drone of the mission.
func (m *manager) waitReady(ctx context.Context) error {
	missing := map[uint16]bool{}
	for _, d := range m.cfg.drones {
		missing[d] = true
	}
	for len(missing) > 0 {
		select {
		case d := <-m.n.ready:
			if missing[d] {
				delete(missing, d)
				log.Printf("drone %d ready (%d to go)", d, len(missing))
			}
		case <-ctx.Done():
			return ctx.Err()
		}
	}
	close(m.allReady)
	return nil
}

// fly is one drone's mission as sequential code: Start_Mission, the challenge, End_Mission,
// each unicast and blocking until ACKed (MCP-FLOW-2..6, MCP-BLK-3, MCP-FLOW-3).
func (m *manager) fly(ctx context.Context, drone uint16) error {
	select {
	case <-m.allReady:
	case <-ctx.Done():
		return ctx.Err()
	}
	err := m.n.unicast(ctx, drone, actStartMission, nil)
	if err == nil && m.cfg.speed > 0 {
		frame := commandLongV1(byte(drone), byte(drone), 178, [7]float32{1, float32(m.cfg.speed), -1})
		err = m.n.unicast(ctx, drone, actMavPassthrough, frame)
	}
	if m.cfg.broadcastLists {
		m.started.Done()
		if err != nil {
			return err
		}
		select {
		case <-m.listed:
		case <-ctx.Done():
			return ctx.Err()
		}
	} else {
		for i := 0; err == nil && i < len(m.cmds); i++ {
			err = m.n.unicast(ctx, drone, m.cmds[i].act, m.cmds[i].payload)
			if err == nil && m.cmds[i].act == actWPOn && m.cfg.hold > 0 {
				err = sleep(ctx, m.cfg.hold)
			}
		}
	}
	if err != nil {
		return err
	}
	return m.n.unicast(ctx, drone, actEndMission, nil)
}

// broadcastChallenge (-broadcast-lists, D-11): once every Start_Mission is ACKed (or given
// up), the challenge goes once to the broadcast ID.
func (m *manager) broadcastChallenge(ctx context.Context) error {
	m.started.Wait()
	defer close(m.listed)
	for _, cmd := range m.cmds {
		if err := m.n.broadcast(ctx, cmd.act, cmd.payload); err != nil {
			return err
		}
		if cmd.act == actWPOn && m.cfg.hold > 0 {
			if err := sleep(ctx, m.cfg.hold); err != nil {
				return err
			}
		}
	}
	return nil
}

func sleep(ctx context.Context, d time.Duration) error {
	select {
	case <-time.After(d):
		return nil
	case <-ctx.Done():
		return ctx.Err()
	}
}

func run(ctx context.Context, cfg config) int {
	wps, err := readWaypoints(cfg.waypoints)
	if err != nil {
		log.Print(err)
		return 2
	}
	var obs []item
	if cfg.challenge == 3 {
		if obs, err = readWaypoints(cfg.obstacles); err != nil {
			log.Print(err)
			return 2
		}
	}
	laddr, err := net.ResolveUDPAddr("udp4", cfg.bind)
	if err != nil {
		log.Printf("-bind: %v", err)
		return 2
	}
	raddr, err := net.ResolveUDPAddr("udp4", cfg.sendTo)
	if err != nil {
		log.Printf("-send-to: %v", err)
		return 2
	}
	conn, err := net.ListenUDP("udp4", laddr) // Go sets SO_BROADCAST on UDP sockets
	if err != nil {
		log.Print(err)
		return 2
	}
	_ = conn.SetReadBuffer(4 << 20) // a flood of malformed datagrams (MCP-ROB-7)
	initial := uint16(rand.N(65536))
	if cfg.initialSeq >= 0 {
		initial = uint16(cfg.initialSeq)
	}
	n := newNode(conn, raddr, cfg.drones, initial)
	n.broadcastID, n.rto, n.retries, n.verbose = cfg.broadcastID, cfg.rto, cfg.retries, cfg.verbose
	n.ackKeepsSeq, n.replyToSource = cfg.ackKeepsSeq, cfg.replyToSource
	if cfg.separateSend {
		if n.out, err = net.ListenUDP("udp4", &net.UDPAddr{IP: laddr.IP}); err != nil {
			log.Print(err)
			return 2
		}
		defer n.out.Close()
	}
	readerDone := make(chan struct{})
	go func() { n.read(); close(readerDone) }()
	defer func() { conn.Close(); <-readerDone }()
	log.Printf("manager on %v, sending to %v: drones %v, challenge %d, rto %v, %d retries",
		conn.LocalAddr(), raddr, cfg.drones, cfg.challenge, cfg.rto, cfg.retries)

	ctx, cancel := context.WithCancel(ctx)
	defer cancel()
	if cfg.exitOnGiveUp {
		n.gaveUp = cancel
	}
	m := &manager{cfg: cfg, n: n, cmds: challengeCommands(cfg, wps, obs),
		allReady: make(chan struct{}), listed: make(chan struct{})}
	m.started.Add(len(cfg.drones))
	var wg sync.WaitGroup
	var mu sync.Mutex
	lost := 0
	for _, d := range cfg.drones {
		wg.Add(1)
		go func() {
			defer wg.Done()
			err := m.fly(ctx, d)
			switch {
			case err == nil:
				log.Printf("drone %d: mission ended", d)
			case errors.Is(err, errGaveUp):
				// The documents say nothing of what follows a give-up: this drone's mission is
				// abandoned (nothing more is sent to it), the others go on (-exit-on-give-up: all end).
				log.Printf("drone %d: %v; its mission is abandoned", d, err)
				mu.Lock()
				lost++
				mu.Unlock()
			}
		}()
	}
	if cfg.broadcastLists {
		go func() { _ = m.broadcastChallenge(ctx) }()
	}
	if err := m.waitReady(ctx); err != nil {
		cancel()
	}
	wg.Wait()
	if ctx.Err() == nil && cfg.linger > 0 {
		_ = sleep(ctx, cfg.linger)
	}
	if lost > 0 {
		return 1
	}
	return 0
}

func main() {
	log.SetFlags(log.Lmicroseconds)
	log.SetPrefix("manager: ")
	cfg, err := parseFlags(os.Args[1:])
	if err != nil {
		if errors.Is(err, flag.ErrHelp) {
			os.Exit(0)
		}
		fmt.Fprintln(os.Stderr, "manager:", err)
		os.Exit(2)
	}
	ctx, cancel := context.WithCancel(context.Background())
	sigs := make(chan os.Signal, 1)
	signal.Notify(sigs, syscall.SIGINT, syscall.SIGTERM)
	var got os.Signal
	var once sync.Once
	go func() {
		s := <-sigs
		log.Printf("%v: stopping", s)
		once.Do(func() { got = s })
		cancel()
	}()
	code := run(ctx, cfg)
	once.Do(func() {})
	if s, ok := got.(syscall.Signal); ok {
		code = 128 + int(s) // 130 for SIGINT, 143 for SIGTERM
	}
	os.Exit(code)
}
