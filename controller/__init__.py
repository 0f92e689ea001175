"""heliocal: heliostat calibration controller.

Layers, from the wire up:
  firmware_proto/        transports' codecs, register map, simulated firmware
  controller/devices/    drivers: serial drive, Modbus drive, cameras
  controller/geometry/   pure maths: sun, frames, aiming, actuators, error model
  controller/imaging/    pure maths: CRF, HDR merge, beam analysis, Hu moments
  controller/flux/       pure maths: PHLUX flux maps, glare hazard
  controller/calibration/  error library, matching, state machine, campaigns
  controller/storage/, controller/reports/, controller/commands/  interfaces
"""

__version__ = "0.1.0"
