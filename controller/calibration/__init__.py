"""Calibration: error library and matching (domain), state machine and campaigns (orchestration)."""
