"""The pipeline's stages, each one library function shared by the CLI and ``kmpipe run``: measure, ingest,
ingest-raw, fit, validate, plan a render, render, lay out a contact sheet."""
