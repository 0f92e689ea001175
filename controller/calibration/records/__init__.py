"""The records a calibration makes (runs, measurements, campaigns) and the observers a campaign
reports to. The bottom of the calibration package: imports only the pure domain and the
foundation (errors, configuration), never another calibration sub-package.
"""
