"""The download-and-correct station: devices in, verified raw copies and corrected MCAP logs out.

Modules: ``ledger`` (SQLite record of everything done to a device), ``download`` (the verified
copy with the online pipeline running on it), ``worker`` (one process per download, cancelled
with a bound, ending with the station), ``completion`` (the ledger completes a download; what a
killed station left is reconciled), ``names`` (the output folder's file names), ``clearing`` (the only code path that clears a device), ``profile`` and
``configure`` (study profile -> device settings), ``flow`` (one device through its states),
``station`` (the watch loop and its table), ``inbox`` (GENEActiv/.cwa files dropped in a folder),
``preview`` (the STREAM preview to MCAP).
"""
