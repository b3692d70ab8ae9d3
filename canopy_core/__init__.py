"""Canopy's measurement core: RGB-D captures of a fruit tree in, its registered cloud and metrics out.

Pure library (numpy, scipy, Open3D, OpenCV, Pillow): no web, no database. Start from
:func:`canopy_core.measure.measure` and :func:`canopy_core.capture.load_capture`. Submodules are imported
on demand so that the command line and the service start fast; this package imports nothing heavy.
"""

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    __version__: str
else:

    def __getattr__(name: str) -> str:
        """``__version__``, the installed distribution's, read from its metadata when first asked for and
        kept (not at every import: the lookup costs every command's start a few milliseconds)."""
        if name != "__version__":
            raise AttributeError(f"module 'canopy_core' has no attribute {name!r}")
        from importlib.metadata import PackageNotFoundError, version

        try:
            found = version("canopy")
        except PackageNotFoundError:  # run from a source tree that was never installed
            found = "0+unknown"
        globals()["__version__"] = found
        return found
