"""Canopy's measurement core: RGB-D captures of a fruit tree in, its registered cloud and metrics out.

Pure library (numpy, scipy, Open3D, OpenCV, Pillow): no web, no database. Start from
:func:`canopy_core.measure.measure` and :func:`canopy_core.capture.load_capture`. Submodules are imported
on demand so that the command line and the service start fast; this package imports nothing heavy.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("canopy")
except PackageNotFoundError:  # run from a source tree that was never installed
    __version__ = "0+unknown"
