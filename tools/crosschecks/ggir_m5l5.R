# GGIR part 2's per-day M10 / L5 on an imputed epoch series written by
# tools/crosschecks/ggir_m5l5.py: each local day's imputed epochs brought to 24 h by
# g.analyse.perday's own lines (the "deltaLength" block, evaluated from GGIR's file), then
# g.getM5L5 with g.analyse.perday's window end (t1_LFMF, R/g.analyse.perday.R:517).
# Usage: Rscript ggir_m5l5.R GGIR_R_DIR DAYS.csv AVDAY.csv OUT.csv
#   DAYS.csv: day (0 = the first local day), enmo_g (imputed); AVDAY.csv: enmo_g (g.impute's
#   average day, slots from the recording's first epoch).
args = commandArgs(trailingOnly = TRUE)
ggir = args[1]
source(file.path(ggir, "g.getM5L5.R"))
src = readLines(file.path(ggir, "g.analyse.perday.R"))
a = grep("NRV = nrow(vari)", src, fixed = TRUE)[1]
b = grep("if (anwi_index != 1) {", src, fixed = TRUE)
b = b[b > a][1] - 1
pad = parse(text = src[a:b])  # GGIR's own lines: pad / trim the day to 24 h
d = read.csv(args[2])
avd = read.csv(args[3])
# GGIR's series carry several metrics (ENMO and anglez at least): two columns keep R's row
# selections matrices, as in GGIR
averageday = as.matrix(data.frame(ENMO = avd$enmo_g, anglez = 0))
ws3 = 5
rows = list()
for (di in sort(unique(d$day)) + 1) {
  vari = data.frame(ENMO = d$enmo_g[d$day == di - 1], anglez = 0)
  colnames(averageday) = colnames(vari)  # R/g.analyse.perday.R:240
  anwi_t0 = 1; anwi_t1 = nrow(vari)
  eval(pad)
  varnum = as.numeric(as.matrix(vari[, 1]))
  r = c(day = di - 1, nrows = length(varnum))
  for (winhr in c(5, 10)) {
    if (length(varnum) > (60 / ws3) * 60 * winhr * 1.2) {
      t1 = length(varnum) / (60 * (60 / ws3)) + (winhr - (10 / 60))
      m = g.getM5L5(varnum, epochSize = ws3, 0, t1, 10, winhr)
      r[paste0("L", winhr, "hr")] = sprintf("%.17g", m[[1]]); r[paste0("L", winhr)] = sprintf("%.17g", m[[2]])
      r[paste0("M", winhr, "hr")] = sprintf("%.17g", m[[3]]); r[paste0("M", winhr)] = sprintf("%.17g", m[[4]])
    }
  }
  rows[[length(rows) + 1]] = as.data.frame(t(r))
}
cols = Reduce(union, lapply(rows, names))
rows = lapply(rows, function(r) { for (m in setdiff(cols, names(r))) r[[m]] = NA; r[cols] })
write.csv(do.call(rbind, rows), args[4], row.names = FALSE)
