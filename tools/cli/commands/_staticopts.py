"""Options of `process` and `replay` that apply a six-orientation static calibration instead of
the autocalibration (never both): from a JSON file, or the store's latest for the device."""

from __future__ import annotations

from pathlib import Path


def add_static_arguments(p) -> None:
    g = p.add_argument_group("static calibration (instead of the autocalibration)")
    g.add_argument("--static", type=Path, metavar="CAL.json", default=None,
                   help="apply this six-orientation calibration (from `static-calibrate -o`) "
                        "instead of autocalibrating; the gap to the recording is logged")
    g.add_argument("--static-from-store", nargs="?", const="", default=None, metavar="DIR",
                   help="apply the store's latest static calibration of this device "
                        "(default store location, or DIR)")


def resolve_static(args, settings) -> None:
    """Fill ``settings.static_calibration`` from the store when asked (needs the device key)."""
    where = getattr(args, "static_from_store", None)
    if where is None:
        return
    from ._runopts import OptionError
    if getattr(args, "static", None):
        raise OptionError("give --static or --static-from-store, not both")
    from stillpoint.engine.recordings import open_recording
    from stillpoint.engine.calibration import CalibrationStore
    src = open_recording(args.file)
    key = src.info.device_key
    src.close()
    store = CalibrationStore(where or None)
    est = store.latest_static(key)
    if est is None:
        raise OptionError(f"{args.file}: the store ({store.dir}) holds no static calibration of "
                          f"device {key}")
    settings.static_calibration = est.to_dict()
