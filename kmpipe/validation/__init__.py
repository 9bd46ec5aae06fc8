"""Validating a material against its measurements: checks, noise statistics, thresholds, HTML reports."""
