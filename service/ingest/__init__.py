"""Ingestors: sources of frames (simulated farm, recording replay, CAN, serial) feeding the store."""
