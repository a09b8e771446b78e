# GGIR part 5 on an epoch series written by tools/crosschecks/ggir_part5_windows.py: the windows
# (g.part5.definedays, looped as g.part5 does, with its nightsi filters) and each window's time use
# (identify_levels on the whole series, then g.part5_analyseSegment per window, as g.part5 calls
# them with the default bout settings).
# Usage: Rscript ggir_part5_windows.R GGIR_R_DIR SERIES.csv TIMEZONE OUT.csv
#   SERIES.csv: time_s (UTC seconds), diur (0/1: inside a sleep period), acc (mg; part 5's ACC),
#               sib (0/1), nonwear (0/1)
# Writes OUT.csv: type, first, last (1-based epochs, both included) and GGIR's part 5 columns of
# every window it keeps.
args = commandArgs(trailingOnly = TRUE)
ggir = args[1]; series = args[2]; tz = args[3]; out = args[4]
for (f in c("g.part5.definedays.R", "identify_level.R", "g.getbout.R", "g.part5.onsetwaketiming.R",
            "g.part5_analyseSegment.R")) {
  eval(parse(text = gsub("GGIR::", "", readLines(file.path(ggir, f)), fixed = TRUE)))
}
d = read.csv(series)
ws3 = 5
time_POSIX = as.POSIXct(d$time_s, origin = "1970-01-01", tz = tz)
ts = data.frame(time = time_POSIX, diur = d$diur, ACC = d$acc, sibdetection = d$sib,
                nonwear = d$nonwear, guider = "unknown")
tt = unclass(as.POSIXlt(ts$time, tz = tz))
params_phyact = list(boutdur.mvpa = c(10, 5, 1), boutdur.in = c(30, 20, 10),  # g.part5.R:110-112
                     boutdur.lig = c(10, 5, 1), boutcriter.in = 0.9, boutcriter.lig = 0.8,
                     boutcriter.mvpa = 0.8, frag.metrics = c())
levelList = identify_levels(ts = ts, TRLi = 40, TRMi = 100, TRVi = 400, ws3 = ws3,
                            params_phyact = params_phyact)
nightsi_bu = which(tt$sec == 0 & tt$min == 0 & tt$hour == 0)
FM = which(diff(ts$diur) == -1)
SO = which(diff(ts$diur) == 1)
rows = list()
for (timewindowi in c("WW", "MM", "OO")) {
  nightsi = nightsi_bu
  if (timewindowi == "WW") {  # g.part5.R:459-474
    if (length(FM) > 0) nightsi = nightsi[nightsi > FM[1] & nightsi < FM[length(FM)]]
  } else if (timewindowi == "OO") {
    if (length(SO) > 0) nightsi = nightsi[nightsi > SO[1] & nightsi < SO[length(SO)]]
  } else {
    startend_sleep = which(abs(diff(ts$diur)) == 1)
    N12 = (60 / ws3) * 60 * 12
    nightsi = nightsi[nightsi >= (startend_sleep[1] - N12) &
                        nightsi <= (startend_sleep[length(startend_sleep)] + N12)]
  }
  Nwindows = switch(timewindowi, MM = length(nightsi) + 1,
                    WW = length(which(diff(ts$diur) == -1)), OO = length(which(diff(ts$diur) == 1)))
  lastDay = !(Nwindows > 0 && length(nightsi) > 0)
  wi = 1; qqq_backup = c(); add_one = FALSE
  while (lastDay == FALSE) {
    dd = g.part5.definedays(nightsi, wi, 1, epochSize = ws3, qqq_backup, ts, timewindowi, Nwindows,
                            qwindow = c(0, 24), ID = "x", dayborder = 0)
    qqq_backup = dd$qqq_backup
    lastDay = dd$lastDay
    qqq = dd$qqq
    if (!any(is.na(qqq)) && (qqq[2] - qqq[1]) * ws3 > 900) {  # g.part5.R:499-500
      seg = dd$segments[[1]]
      indexlog = list(fileIndex = 1, winType = timewindowi, winIndex = wi, winStartEnd = qqq,
                      segIndex1 = 1, segIndex2 = 1, segStartEnd = c(seg[1], seg[2]), columnIndex = 1)
      timeList = list(ts = ts, sec = tt$sec, min = tt$min, hour = tt$hour, time_POSIX = time_POSIX,
                      epochSize = ws3)
      gas = g.part5_analyseSegment(indexlog, timeList, levelList, dd$segments, dd$segments_names,
                                   dsummary = matrix("", 1, 400), ds_names = rep("", 400),
                                   params_general = list(desiredtz = tz),
                                   params_output = list(do.sibreport = FALSE, storefolderstructure = FALSE),
                                   params_sleep = list(), params_247 = list(iglevels = c()),
                                   params_phyact = params_phyact,
                                   sumSleep = data.frame(calendar_date = character(0)), sibDef = "x",
                                   fullFilename = "x", add_one_day_to_next_date = add_one,
                                   lightpeak_available = FALSE, tail_expansion_log = NULL,
                                   foldernamei = "x")
      add_one = gas$add_one_day_to_next_date
      keep = gas$ds_names != ""
      r = as.data.frame(t(gas$dsummary[1, keep]), stringsAsFactors = FALSE)
      names(r) = gas$ds_names[keep]
      r = cbind(data.frame(type = timewindowi, first = qqq[1], last = qqq[2]), r)
      rows[[length(rows) + 1]] = r
    }
    wi = wi + 1
    if (wi > Nwindows + 2) break
  }
}
cols = Reduce(union, lapply(rows, names))
rows = lapply(rows, function(r) { for (m in setdiff(cols, names(r))) r[[m]] = NA; r[cols] })
write.csv(do.call(rbind, rows), out, row.names = FALSE)
