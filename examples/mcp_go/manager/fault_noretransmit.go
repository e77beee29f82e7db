//go:build fault_noretransmit

package main

// A faulty build (go build -tags fault_noretransmit): each unicast is sent once and never
// retransmitted; its ACK is awaited for the same total time (rto x (1 + retries)). Breaks
// MCP-RTX-1.
const (
	faultNoRetransmit = true
	faultPipeline     = false
)
