"""stillpoint: a streaming engine for raw wearable-accelerometer data (AX3/AX6 .cwa, GENEActiv
.bin) - readers in ``stillpoint.drivers``, the engine in ``stillpoint.engine``, the command line
in ``stillpoint.tools``. ``__version__`` is the installed distribution's version (looked up on
first use: importing the package stays quick, so the command line's own Ctrl-C handling is in
place almost at once).

DataFrames (the optional ``pandas`` extra; ``stillpoint.engine.dataframes``):
``stillpoint.read(path, calibrate=..., resample=...)``, the samples with a time index;
``stillpoint.tables(path_or_mcap)``, the epoch/day (and night) tables."""


def read(path, *, calibrate=False, resample=None, timezone=None, timezone_override=False):
    """The samples of a recording as a pandas DataFrame (``stillpoint.engine.dataframes.read``)."""
    from stillpoint.engine.dataframes import read as _read
    return _read(path, calibrate=calibrate, resample=resample, timezone=timezone,
                 timezone_override=timezone_override)


def tables(path, *, timezone=None):
    """The epoch/day (and night) tables as pandas DataFrames
    (``stillpoint.engine.dataframes.tables``)."""
    from stillpoint.engine.dataframes import tables as _tables
    return _tables(path, timezone=timezone)


def __getattr__(name):
    if name != "__version__":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    try:
        from importlib.metadata import PackageNotFoundError, version
        try:
            v = version("stillpoint")
        except PackageNotFoundError:  # running from a source tree that was never installed
            v = "0+unknown"
    except ImportError:  # pragma: no cover
        v = "0+unknown"
    globals()["__version__"] = v
    return v


def main():
    """The ``stillpoint`` command (``stillpoint.tools.cli.main``): a Ctrl-C while the command
    line itself is imported exits 130 with one line, as it does later."""
    try:
        from stillpoint.tools.cli import main as cli_main
    except KeyboardInterrupt:
        import sys
        print("stillpoint: interrupted", file=sys.stderr)
        return 130
    return cli_main()
