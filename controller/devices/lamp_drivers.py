"""The lamp panel a configuration names, opened (docs/lamps.md): the Modbus driver
(:mod:`controller.devices.lamp_modbus`) or the plant's switch program
(:mod:`controller.devices.lamp_command`), and the fiducial lamps' switch built on either.

Above the drivers (imported when a panel is opened, so importing the panel loads no Modbus
client), which build on :mod:`controller.devices.lamp_panel` (the panel, its states
and errors, switching with confirmation).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager

from controller.devices.lamp_panel import LampPanel, set_and_confirm
from controller.devices.plant_time import WALL, PlantTime
from controller.lamp_config import FIDUCIALS


def open_lamp_panel(cfg) -> LampPanel:
    """The panel the ``lamps:`` section ``cfg`` names (nothing is sent yet)."""
    if cfg.driver == "command":
        from controller.devices.lamp_command import CommandLampPanel

        return CommandLampPanel(cfg.command, tuple(cfg.channels), cfg.timeout_s)
    from controller.devices.lamp_modbus import ModbusLampPanel

    return ModbusLampPanel.from_config(cfg)


@contextmanager
def fiducial_switch(cfg, hook: Callable[[bool], None],
                    time: PlantTime = WALL) -> Iterator[Callable[[bool], None]]:
    """``switch(on)`` for the fiducial lamps of ``cfg``'s calibration target (``cfg`` a
    PlantConfig): through the panel's ``fiducials:<target>`` channel, confirmed, when the
    ``lamps:`` section has one; else through ``camera.registration.lamp_command``; else
    ``hook`` (the simulator's, an operator's). The panel is closed on leaving."""
    from controller.devices.lamp_command import LAMP_COMMAND_TIMEOUT_S, fiducial_command_panel

    channel = FIDUCIALS + cfg.calibration.target
    reg = cfg.camera.registration
    if cfg.lamps is not None and channel in cfg.lamps.channels:
        panel, timeout_s = open_lamp_panel(cfg.lamps), cfg.lamps.confirm_timeout_s
    elif reg is not None and reg.lamp_command:
        (panel, channel), timeout_s = fiducial_command_panel(reg.lamp_command), LAMP_COMMAND_TIMEOUT_S
    else:
        yield hook
        return
    with panel:
        yield lambda on: set_and_confirm(panel, channel, on, time=time, timeout_s=timeout_s)
