# GGIR part 5's window edges (g.part5.definedays, looped as g.part5 does) on a sleep-period series
# written by tools/crosschecks/ggir_part5_windows.py.
# Usage: Rscript ggir_part5_windows.R GGIR_R_DIR SERIES.csv TIMEZONE OUT.csv
#   SERIES.csv: time_s (UTC seconds), diur (0/1: inside a sleep period)
# Writes OUT.csv: type, first, last (1-based epochs, both included) of every window it keeps.
args = commandArgs(trailingOnly = TRUE)
ggir = args[1]; series = args[2]; tz = args[3]; out = args[4]
eval(parse(text = gsub("GGIR::", "", readLines(file.path(ggir, "g.part5.definedays.R")), fixed = TRUE)))
d = read.csv(series)
ts = data.frame(time = as.POSIXct(d$time_s, origin = "1970-01-01", tz = tz), diur = d$diur)
tt = unclass(as.POSIXlt(ts$time, tz = tz))
nightsi0 = which(tt$sec == 0 & tt$min == 0 & tt$hour == 0)
rows = list()
for (timewindowi in c("WW", "MM", "OO")) {
  nightsi = nightsi0
  Nwindows = switch(timewindowi, MM = length(nightsi) + 1,
                    WW = length(which(diff(ts$diur) == -1)), OO = length(which(diff(ts$diur) == 1)))
  lastDay = !(Nwindows > 0 && length(nightsi) > 0)
  wi = 1; qqq_backup = c()
  while (lastDay == FALSE) {
    dd = g.part5.definedays(nightsi, wi, 1, epochSize = 5, qqq_backup, ts, timewindowi, Nwindows,
                            qwindow = c(0, 24), ID = "x", dayborder = 0)
    qqq_backup = dd$qqq_backup
    lastDay = dd$lastDay
    if (!any(is.na(dd$qqq))) rows[[length(rows) + 1]] = data.frame(type = timewindowi,
                                                                   first = dd$qqq[1], last = dd$qqq[2])
    wi = wi + 1
    if (wi > Nwindows + 2) break
  }
}
write.csv(do.call(rbind, rows), out, row.names = FALSE)
