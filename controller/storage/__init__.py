"""Calibration records in SQLite (WAL, versioned schema, transactions) and exports.

Sub-packages: :mod:`~controller.storage.paint` (PAINT files in and out) and
:mod:`~controller.storage.reprocess` (what archive reprocessing reads and writes).
"""
