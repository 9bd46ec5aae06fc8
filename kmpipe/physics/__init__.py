"""The physics: Kubelka-Munk, Saunderson, the closed-form inversions, the joint fit, colorimetry, white normalization,
camera colour correction and the render's optical tables.

Modules here import only numpy, scipy, colour-science and nlopt, and from kmpipe only :mod:`kmpipe.errors` and
:mod:`kmpipe.formats` (for the files some of them read).
"""
