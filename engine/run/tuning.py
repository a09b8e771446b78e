"""Tuning constants of a run, in one place: one line each, with why it has its value.

The measurements behind them are on the performance page (docs/performance.md, "Run tuning").
Code reads them as ``tuning.NAME`` so a benchmark or a test can change one here.
"""

# MCAP chunk span (s) when RunSettings.chunk_s is None: fewer bytes than one chunk per 10 s cell
CHUNK_S = 60.0
# MCAP writer when process_file is given none: batch compresses on a thread, online inline (a kill loses no queued step)
WRITER_BY_MODE = {"batch": "thread", "online": "inline"}
# read ahead on a thread (with a second core): batch only; the station's online run reads in the engine's thread
PREFETCH_BY_MODE = {"batch": True, "online": False}
# .cwa sectors an output pass reads at a time: about one pipeline step (10 min at 100 Hz), so read-ahead stays small
OUTPUT_BATCH_SECTORS = 500
# the tables' own pass (an online run's tables, tables from a log): .cwa sectors read at a time, the longest step (s)
# its blocks are joined into, 40 min at 100 Hz, and the most samples a step holds at any rate (2,000 sectors of 120):
# each step costs ~1.5 ms in its operators whatever its length (a week, that pass alone, bench_tables_pass.py: 10-min
# steps 7.82 CPU-s / 55 MB peak RSS, 40 min 7.03 / 88 MB; docs/performance.md#run-tuning)
TABLES_PASS_SECTORS = 2000
TABLES_PASS_STEP_S = 2400.0
TABLES_PASS_SAMPLES = 240_000
# QC events described in the run summary (all are counted, and logged on /qc)
QC_DETAILS = 10
# a batch run writes its MCAP log in a child process (engine/mcap/sinkproc.py) for inputs of at least this many
# bytes (~0.9 day of .cwa at 100 Hz): a day's full log 0.86x the wall time for the same CPU, below it the child's
# start-up (~0.6 CPU-s) is not won back
SINK_PROCESS_MIN_BYTES = 32 << 20
