# MIMS-units of the reference implementation (R package MIMSunit, mHealthGroup/MIMSunit, MIT) on
# samples written by tools/crosschecks/mims_reference.py. The package's R files are read from a
# checkout (never copied here) and evaluated with two textual changes: shiny::isRunning() is FALSE
# (shiny is only its progress display) and MIMSunit:: calls go to the functions just read.
# Usage: Rscript mims_reference.R MIMSUNIT_R_DIR SAMPLES.csv RANGE_G EPOCH OUT.csv
#   SAMPLES.csv: t_ns,x,y,z (ns since the Unix epoch, g). OUT.csv: epoch start (s), MIMS_UNIT,
#   MIMS_UNIT_X, MIMS_UNIT_Y, MIMS_UNIT_Z (-0.01: undefined), 17 significant digits.
args = commandArgs(trailingOnly = TRUE)
libs = Sys.getenv("STILLPOINT_R_LIBS")
if (nzchar(libs)) .libPaths(c(strsplit(libs, ":")[[1]], .libPaths()))
suppressMessages({library(magrittr); library(signal); library(plyr); library(dplyr)})
for (f in c("helper.R", "check_epoch.R", "combine_axes.R", "extrapolate.R", "interpolate.R",
            "filter.R", "aggregate_over_epoch.R", "mims_unit.R")) {
  code = readLines(file.path(args[1], f))
  code = gsub("shiny::isRunning()", "FALSE", code, fixed = TRUE)
  code = gsub("MIMSunit::", "", code, fixed = TRUE)
  eval(parse(text = code))
}
d = read.csv(args[2], colClasses = c("numeric", "numeric", "numeric", "numeric"))
r = as.numeric(args[3])
df = data.frame(HEADER_TIME_STAMP = as.POSIXct(d$t_ns / 1e9, origin = "1970-01-01", tz = "UTC"),
                X = d$x, Y = d$y, Z = d$z)
out = mims_unit(df, epoch = paste(args[4], "sec"), dynamic_range = c(-r, r),
                output_mims_per_axis = TRUE)
res = data.frame(t = sprintf("%.17g", as.numeric(out[[1]])))
for (c in c("MIMS_UNIT", "MIMS_UNIT_X", "MIMS_UNIT_Y", "MIMS_UNIT_Z")) res[[c]] = sprintf("%.17g", out[[c]])
write.csv(res, args[5], row.names = FALSE, quote = FALSE)
