"""Pure geometry: solar position, frames, aiming, linear actuators, tracking-error model.

Angles are degrees at the public edges (names end in ``_deg``) and radians inside.
Azimuth is measured clockwise from north; ENU = (east, north, up) metres.
"""
