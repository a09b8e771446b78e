"""stillpoint: a streaming engine for raw wearable-accelerometer data (AX3/AX6 .cwa, GENEActiv
.bin) - readers in ``stillpoint.drivers``, the engine in ``stillpoint.engine``, the command line
in ``stillpoint.tools``. ``__version__`` is the installed distribution's version."""

try:
    from importlib.metadata import PackageNotFoundError, version as _version
    try:
        __version__ = _version("stillpoint")
    except PackageNotFoundError:  # running from a source tree that was never installed
        __version__ = "0+unknown"
except ImportError:  # pragma: no cover
    __version__ = "0+unknown"
