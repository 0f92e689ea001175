"""The field console: a local web page over the controller (``heliocal console``, docs/console.md).

An interface layer like the CLI: a Starlette app (:mod:`controller.console.app`) over a
:class:`controller.console.backend.Console`, which holds the drives, the camera, the
commissioning sessions and the campaign runner. Live updates go out as server-sent events
(:mod:`controller.console.events`). Nothing here knows whether the plant is simulated: the
command hands the simulated plant's links, camera and clock in.
"""
