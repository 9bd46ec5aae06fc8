"""pyserial URL handlers of the instruments package: ``replay://`` (see :mod:`.protocol_replay`).

pyserial finds a handler for ``scheme://`` as a module ``protocol_<scheme>`` in one of the packages listed in
``serial.protocol_handler_packages``. Importing this package adds it there (:func:`register`), after which
``serial.serial_for_url("replay://session.jsonl", timeout=1.0)`` replays a recorded session.
"""

import serial

__all__ = ["register"]


def register() -> None:
    """Add this package to ``serial.protocol_handler_packages`` (idempotent)."""
    if __name__ not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append(__name__)


register()
