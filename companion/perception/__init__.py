"""Perception: range-sensor scans into a local map of trunks (pure: no I/O)."""
