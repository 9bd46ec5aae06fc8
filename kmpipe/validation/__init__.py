"""Validating a material against its measurements: thresholds (``thresholds``), noise statistics (``noise``), the
checks and their registry (``checks``), findings and reports' documents (``findings``), the whole validation of a
material (``material``) and the HTML pages (``report``)."""
