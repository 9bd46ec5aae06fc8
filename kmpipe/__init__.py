"""kmpipe: measurements of cosmetic films to Kubelka-Munk materials and render assets."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("kmpipe")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.0.0+source"
