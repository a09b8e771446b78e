"""The download-and-correct station: devices in, verified raw copies and corrected MCAP logs out.

Modules: ``ledger`` (SQLite record of everything done to a device), ``download`` (the verified copy
with the online pipeline running on it), ``device_read`` (every re-read of a device past the page
cache), ``worker`` (one process per device read, a download or the re-read before a clear,
cancelled with a bound, ending with the station), ``completion`` (the ledger completes a download;
what a killed station left is reconciled), ``names`` (the output folder's file names),
``clearing`` (the only code path that clears a device), ``profile`` and ``configure`` (study
profile -> device settings), ``flow`` (one device through its states), ``station`` (the watch loop
and its table), ``status`` (the ``devices`` listing), ``inbox`` (GENEActiv/.cwa files dropped in a
folder, completed through the ledger too), ``preview`` (the STREAM preview to MCAP).
"""
