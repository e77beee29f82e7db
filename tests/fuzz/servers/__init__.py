"""Test servers the fuzz tests run as targets: plain Python, loopback, bounded in time."""
