# Run GGIR's own sleep functions (g.sib.det -> HASIB vanHees2015 + HASPT HDCZA) on a 5 s series
# written by tools/crosschecks/ggir_sleep_fixtures.py, and write what they decide.
# Usage: Rscript ggir_sleep_fixtures.R GGIR_R_DIR SERIES.csv TIMEZONE IGNORE_INVALID OUT_PREFIX
#   SERIES.csv: timestamp (GGIR's ISO 8601 with %z), anglez, ENMO (= the 1-based epoch index, so
#   each HASPT call can be located), invalid (0/1 per epoch).
#   IGNORE_INVALID: FALSE, TRUE or NA (params_sleep HASPT.ignore.invalid).
# Writes OUT_PREFIX.calls.csv (every HASPT call: first epoch (0-based), length, SPTE_start,
# SPTE_end, threshold, guider), OUT_PREFIX.nights.csv (g.sib.det's SPTE_start / SPTE_end hours and
# guider per night) and OUT_PREFIX.sib.csv (the SIB runs: first epoch, stop; 0-based).
args = commandArgs(trailingOnly = TRUE)
ggir = args[1]; series = args[2]; tz = args[3]; ign = args[4]; out = args[5]
suppressMessages(library(zoo))
for (f in c("HASIB.R", "HASPT.R", "g.sib.det.R", "g.detecmidnight.R", "iso8601chartime2POSIX.R",
            "load_params.R")) {
  # GGIR's files are sourced, not installed: its own "GGIR::f" calls become "f"
  eval(parse(text = gsub("GGIR::", "", readLines(file.path(ggir, f)), fixed = TRUE)))
}
params_sleep = load_params(topic = "sleep")$params_sleep
params_sleep[["HASPT.ignore.invalid"]] = as.logical(ign)
d = read.csv(series, colClasses = c("character", "numeric", "numeric", "numeric"))
metashort = data.frame(timestamp = d$timestamp, anglez = d$anglez, ENMO = d$ENMO,
                       stringsAsFactors = FALSE)
rout = matrix(0, nrow(d), 5)
rout[, 5] = d$invalid
IMP = list(metashort = metashort, rout = as.data.frame(rout))
M = list(windowsizes = c(5, 5, 3600), metashort = metashort)  # ws2 = 5 s: one invalid flag per epoch
I = list(monn = "axivity")
HASPT_ggir = HASPT
calls = list()
HASPT = function(angle, params_sleep = NULL, ws3 = 5, HASPT.algo = "HDCZA", invalid,
                 activity = NULL, marker = NULL, sibs = NULL) {
  r = HASPT_ggir(angle = angle, params_sleep = params_sleep, ws3 = ws3, HASPT.algo = HASPT.algo,
                 invalid = invalid, activity = activity, marker = marker, sibs = sibs)
  calls[[length(calls) + 1]] <<- data.frame(
    first = activity[1] - 1, n = length(angle),
    start = ifelse(length(r$SPTE_start) > 0, r$SPTE_start, NA),
    end = ifelse(length(r$SPTE_end) > 0, r$SPTE_end, NA),
    threshold = sprintf("%.17g", ifelse(length(r$tib.threshold) > 0, r$tib.threshold, NA)),
    guider = ifelse(length(r$part3_guider) > 0, r$part3_guider, NA))
  r
}
SLE = g.sib.det(M, IMP, I, twd = c(-12, 12), acc.metric = "ENMO", desiredtz = tz,
                params_sleep = params_sleep)
write.csv(do.call(rbind, calls), paste0(out, ".calls.csv"), row.names = FALSE)
write.csv(data.frame(spte_start_h = sprintf("%.17g", SLE$SPTE_start),
                     spte_end_h = sprintf("%.17g", SLE$SPTE_end),
                     guider = SLE$part3_guider), paste0(out, ".nights.csv"), row.names = FALSE)
if (is.null(SLE$output)) {
  # shorter than g.sib.det's 0.2-day minimum: no nights; GGIR's HASIB on the whole series
  a = d$anglez
  a[is.na(a)] = 0
  s = as.numeric(HASIB(HASIB.algo = "vanHees2015", timethreshold = params_sleep[["timethreshold"]],
                       anglethreshold = params_sleep[["anglethreshold"]], time = d$timestamp,
                       anglez = a, ws3 = 5, activity = d$ENMO)[, 1])
} else {
  s = as.numeric(SLE$output[, 4])
}
r = rle(s)
ends = cumsum(r$lengths)
starts = ends - r$lengths
keep = r$values == 1
write.csv(data.frame(first = starts[keep], stop = ends[keep]), paste0(out, ".sib.csv"),
          row.names = FALSE)
