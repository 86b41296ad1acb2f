"""``cdpr commission``: commissioning the real winches and load cells (and ``cdpr sim``).

One module per sub-command or concern: :mod:`.scan`, :mod:`.check`, :mod:`.motion`
(enable, disable, jog, home), :mod:`.loadcells` (tare, calibrate), :mod:`.monitor`,
:mod:`.report` (the commissioning report), :mod:`.files` (parameter files rewritten with a
backup), :mod:`.common` (bus, confirmation, output). Hardware access lives in the HAL
(:mod:`hal.scan`, :mod:`hal.sdo_config`, :mod:`hal.motion`, :mod:`hal.drive_monitor`);
the command front is :mod:`bench.commands.commission`.
"""
