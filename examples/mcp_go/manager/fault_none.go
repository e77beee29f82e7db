//go:build !fault_noretransmit && !fault_pipeline

package main

// The correct build: no fault.
const (
	faultNoRetransmit = false
	faultPipeline     = false
)
