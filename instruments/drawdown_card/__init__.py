"""The drawdown card: a printed card with ArUco markers, located in a photo so that its regions can be sampled.

A technician draws a cosmetic film down over the black and white stripes of a printed card and photographs it
through crossed polarizers. The modules follow the card's life:

- :mod:`~instruments.drawdown_card.layout`: the card (:class:`~instruments.drawdown_card.layout.Layout`: size,
  markers, printed areas, regions) and its rules; the bundled :func:`~instruments.drawdown_card.layout.default_layout`.
- :mod:`~instruments.drawdown_card.printing`: the printable card (PNG or PDF at 300 dpi).
- :mod:`~instruments.drawdown_card.locate`: the card found in a photo (ArUco markers, then a homography from card
  millimetres to image pixels).
- :mod:`~instruments.drawdown_card.sampling`: the statistics of a region of the linear photo.
- :mod:`~instruments.drawdown_card.flat_field`: the light across the card, from its bare paper.

The layout file (TOML, ``docs/formats.md``) is read and written by ``kmpipe.formats.card_layout``; nothing here
imports kmpipe.

Coordinates
-----------
Card coordinates are in mm from the card's top-left corner, x to the right and y down. Image coordinates are in px
with OpenCV's convention: the centre of pixel (column i, row j) is at (i, j), so a rendered card at ``px_per_mm``
maps card (x, y) mm to image (x * px_per_mm - 0.5, y * px_per_mm - 0.5) px.

Markers
-------
A marker's ``x_mm``, ``y_mm`` is the top-left corner of its black square (border included) and ``size_mm`` its side.
It is printed upright. Around the square a quiet zone one module wide (``size_mm / (bits + 2)``, e.g. 1/6 of the
side for a 4x4 dictionary) must stay white: printed areas may not enter it, regions keep a further 1 mm away (room
for their outlines), and it must lie on the card.
"""
