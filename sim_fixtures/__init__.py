"""Simulated world and simulated devices speaking the real protocols."""
