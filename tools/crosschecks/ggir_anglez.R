# GGIR's anglez per epoch (g.applymetrics, do.anglez only) on raw samples written by
# tools/crosschecks/ggir_anglez.py. Usage: Rscript ggir_anglez.R GGIR_R_DIR RAW.csv SF BLOCK OUT.csv
#   RAW.csv: x,y,z (g); the samples are given to g.applymetrics in blocks of BLOCK samples, as
#   GGIR's part 1 does with the blocks it reads. OUT.csv: angle_z per 5 s epoch. FIX = "fix": the
#   line "xm = x[1:LX]" of its rolling median (the raw samples where the smoothed ones were
#   meant) reads "xm = xm[1:LX]", to show what that line changes.
args = commandArgs(trailingOnly = TRUE)
suppressMessages(library(zoo))
code = readLines(file.path(args[1], "g.applymetrics.R"))
if (length(args) > 5 && args[6] == "fix") code = sub("xm = x[1:LX]", "xm = xm[1:LX]", code, fixed = TRUE)
eval(parse(text = code))
d = as.matrix(read.csv(args[2]))
sf = as.numeric(args[3]); block = as.integer(args[4])
flags = c("anglex", "angley", "anglez", "bfen", "bfx", "bfy", "bfz", "brondcounts",
          "dev_roll_med_acc_x", "dev_roll_med_acc_y", "dev_roll_med_acc_z", "en", "enmo", "enmoa",
          "hfen", "hfenplus", "hfx", "hfy", "hfz", "lfen", "lfenmo", "lfx", "lfy", "lfz", "mad",
          "neishabouricounts", "roll_med_acc_x", "roll_med_acc_y", "roll_med_acc_z", "zcx", "zcy", "zcz")
m2d = setNames(as.list(rep(FALSE, length(flags))), paste0("do.", flags))
m2d$do.anglez = TRUE
out = c()
for (s in seq(1, nrow(d), by = block)) {
  e = min(nrow(d), s + block - 1)
  out = c(out, g.applymetrics(d[s:e, , drop = FALSE], sf = sf, ws3 = 5, metrics2do = m2d)$angle_z)
}
write.csv(data.frame(angle_z = sprintf("%.17g", out)), args[5], row.names = FALSE)
