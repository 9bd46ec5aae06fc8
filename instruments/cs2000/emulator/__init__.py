"""A Konica Minolta CS-2000A emulator speaking the serial protocol, on a pseudo-terminal and/or a TCP socket.

The emulator answers the commands the pipeline uses (see :mod:`instruments.cs2000.protocol` and the protocol
summary) with the instrument's timing: ``MEAS,1`` pre-measures for 1-3 s while it reads and ignores input, answers
``OK00,NNN``, and sends the unsolicited completion ``OK00`` NNN s later. All instrument times are multiplied by
``time_scale`` (tests use 0.01); the announced NNN is not. ``kmpipe emulate`` serves one from a samples script.

Modules
-------
- :mod:`~instruments.cs2000.emulator.radiometry`: the radiance of a sample (illuminant x reflectance x gain) and
  its 24 colorimetric values.
- :mod:`~instruments.cs2000.emulator.faults`: :class:`~instruments.cs2000.emulator.faults.Fault`, the injectable
  misbehaviour.
- :mod:`~instruments.cs2000.emulator.timing`: how long a measurement takes, and the luminance range.
- :mod:`~instruments.cs2000.emulator.instrument`: the instrument's state machine (settings, the sample under it,
  measuring, the replies), free of any transport.
- :mod:`~instruments.cs2000.emulator.transports`: the pseudo-terminal and TCP ends the host talks to.
- :mod:`~instruments.cs2000.emulator.server`: :class:`~instruments.cs2000.emulator.server.Emulator`, the instrument
  served on those transports by a background thread.

Nothing here reads files: ``kmpipe.formats.emulator_script`` reads a samples script and hands over plain values.
"""
