"""Instrument drivers: drawstring sensor, dial indicator, robot joint source."""
