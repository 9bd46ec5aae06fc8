"""Konica Minolta CS-2000 / CS-2000A spectroradiometer: protocol, driver and emulator."""
