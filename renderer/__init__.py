"""The bundled OSMesa renderer. Never imports kmpipe."""
