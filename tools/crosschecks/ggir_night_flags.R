# GGIR's per-night fraction of invalid data (g.sib.det, then g.sib.sum as part 3 calls it) on a
# 5 s series written by tools/crosschecks/ggir_night_flags.py.
# Usage: Rscript ggir_night_flags.R GGIR_R_DIR SERIES.csv TIMEZONE OUT.csv
#   SERIES.csv: timestamp (ISO 8601 with %z), anglez, ENMO, invalid (0/1)
# Writes OUT.csv: night, start (the night's first timestamp), fraction_night_invalid.
args = commandArgs(trailingOnly = TRUE)
ggir = args[1]; series = args[2]; tz = args[3]; out = args[4]
suppressMessages(library(zoo))
for (f in c("HASIB.R", "HASPT.R", "g.sib.det.R", "g.detecmidnight.R", "iso8601chartime2POSIX.R",
            "POSIXtime2iso8601.R", "load_params.R", "g.sib.sum.R")) {
  eval(parse(text = gsub("GGIR::", "", readLines(file.path(ggir, f)), fixed = TRUE)))
}
params_sleep = load_params(topic = "sleep")$params_sleep
d = read.csv(series, colClasses = c("character", "numeric", "numeric", "numeric"))
metashort = data.frame(timestamp = d$timestamp, anglez = d$anglez, ENMO = d$ENMO,
                       stringsAsFactors = FALSE)
rout = matrix(0, nrow(d), 5)
rout[, 5] = d$invalid
IMP = list(metashort = metashort, rout = as.data.frame(rout))
M = list(windowsizes = c(5, 5, 3600), metashort = metashort)
SLE = g.sib.det(M, IMP, list(monn = "axivity"), twd = c(-12, 12), acc.metric = "ENMO",
                desiredtz = tz, params_sleep = params_sleep)
S = g.sib.sum(SLE, M, ignorenonwear = TRUE, desiredtz = tz)
S = S[!duplicated(S$night), ]
write.csv(data.frame(night = S$night, start = S$start.time.day,
                     fraction_night_invalid = sprintf("%.17g", S$fraction.night.invalid)),
          out, row.names = FALSE)
