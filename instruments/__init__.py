"""Measuring devices: the CS-2000 protocol and driver, sessions, RAW photos. Never imports kmpipe."""
