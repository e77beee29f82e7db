//go:build fault_pipeline

package main

// A faulty build (go build -tags fault_pipeline), the reading of "the call blocks" as per
// drone: each drone's goroutine waits for its own ACKs only, so messages to different drones
// are outstanding at once. Breaks MCP-BLK-1 ("a node sends no new unicast message other than
// an ACK while one of its unicast messages awaits its ACK").
const (
	faultNoRetransmit = false
	faultPipeline     = true
)
