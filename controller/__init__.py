"""heliocal: heliostat calibration controller.

Layers, from the wire up:
  firmware_proto/        transports' codecs, register map, simulated firmware
  controller/devices/    drivers: serial drive, Modbus drive, cameras
  controller/geometry/   pure maths: sun, frames, aiming, actuators, tracking model (model/)
  controller/imaging/    pure maths: CRF, HDR merge, beam analysis, Hu moments
  controller/flux/       pure maths: PHLUX flux maps, glare hazard
  controller/recognition/  pure maths: the Hu-moment error library and its matching
  controller/calibration/  orchestration: the measurement cycle (cycle/), campaigns (campaign/),
                           planned nights (night/), several beams on a target (beams/), model
                           updates (model/), archive reprocessing (reprocess/), records (records/)
  controller/storage/, controller/reports/, controller/commands/  interfaces
"""

__version__ = "0.1.0"
