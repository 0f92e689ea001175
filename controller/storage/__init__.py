"""Calibration records in SQLite (WAL, versioned schema, transactions) and exports."""
