# Run GGIR's own rhythm functions on an epoch series written by
# tools/crosschecks/ggir_rhythm_fixtures.py and write what they compute.
# Usage: Rscript ggir_rhythm_fixtures.R GGIR_R_DIR ACTCR_R_FILE SERIES.csv TIMEZONE OUT_PREFIX
#   SERIES.csv: time_s (UTC seconds of the epoch start), local (GGIR's ISO 8601 with %z),
#   enmo_g (ENMO in g), invalid (0/1), midnight (0/1: the epoch starts at local midnight),
#   sib (0/1), level (part 5's class id, 0-based, of engine/timeuse/levels.py; NA: invalid),
#   spt (0/1: in a sleep period).
#   ACTCR_R_FILE: ActCR's ActCosinor / ActExtendCosinor (and cosinor.lm, correct.acrophase).
# Writes OUT_PREFIX.cosinor.csv (apply_cosinor_IS_IV_Analyses with epochsizes c(5, 5) and the
# light threshold 40 mg: one row), OUT_PREFIX.sri.csv (CalcSleepRegularityIndex on the SIBs, per
# day pair) and OUT_PREFIX.frag.csv (g.fragmentation with every metric, modes "day" and "spt" as
# part 6 calls it: the other part of the day missing). ineq is not packaged for Debian: its Gini
# (ineq 0.2-13, R/ineq.R, which g.fragmentation calls as ineq::Gini) is transcribed below.
args = commandArgs(trailingOnly = TRUE)
ggir = args[1]; actcr = args[2]; series = args[3]; tz = args[4]; out = args[5]
suppressMessages(library(zoo))
suppressMessages(library(minpack.lm))
ActCR = new.env()
sys.source(actcr, envir = ActCR)
for (f in c("g.IVIS.R", "cosinor_IS_IV_Analyses.R", "apply_cosinor_IS_IV_Analyses.R",
            "CalcSleepRegularityIndex.R", "iso8601chartime2POSIX.R", "g.fragmentation.R")) {
  # GGIR's files are sourced, not installed: "ActCR::f" calls go to the ActCR environment
  txt = gsub("ActCR::", "ActCR$", readLines(file.path(ggir, f)), fixed = TRUE)
  txt = gsub("ineq::", "", txt, fixed = TRUE)
  eval(parse(text = gsub("GGIR::", "", txt, fixed = TRUE)))
}
Gini = function(x, corr = FALSE, na.rm = TRUE) {
  if (!na.rm && any(is.na(x))) return(NA_real_)
  x = as.numeric(na.omit(x))
  n = length(x)
  x = sort(x)
  G = sum(x * 1L:n)
  G = 2 * G / sum(x) - (n + 1L)
  if (corr) G / (n - 1L) else G / n
}
d = read.csv(series, colClasses = c("numeric", "character", "numeric", "numeric", "numeric",
                                    "numeric", "numeric", "numeric", "numeric"))
num = function(x) if (is.null(x) || length(x) == 0) "NA" else sprintf("%.17g", as.numeric(x))
cc = apply_cosinor_IS_IV_Analyses(ts = data.frame(time = d$time_s, ENMO = d$enmo_g),
                                  qcheck = d$invalid, midnightsi = which(d$midnight == 1),
                                  epochsizes = c(5, 5), threshold = 40)
if (length(cc) > 0) {
  p = cc$coef$params; e = cc$coefext$params
  row = c(timeOffsetHours = num(cc$timeOffsetHours), mes = num(p$mes), amp = num(p$amp),
          acr = num(p$acr), acrotime = num(p$acrotime), ndays = num(p$ndays), R2 = num(p$R2),
          ext_minimum = num(e$minimum), ext_amp = num(e$amp), ext_alpha = num(e$alpha),
          ext_beta = num(e$beta), ext_acrotime = num(e$acrotime), ext_F_pseudo = num(e$F_pseudo),
          ext_UpMesor = num(e$UpMesor), ext_DownMesor = num(e$DownMesor),
          ext_MESOR = num(e$MESOR), ext_R2 = num(e$R2),
          IS = num(cc$IVIS$InterdailyStability), IV = num(cc$IVIS$IntradailyVariability),
          phi = num(cc$IVIS$phi))
  write.csv(as.data.frame(t(row)), paste0(out, ".cosinor.csv"), row.names = FALSE)
}
sri = CalcSleepRegularityIndex(data = data.frame(time = d$local, invalid = d$invalid, night = 0,
                                                 sleep = d$sib, stringsAsFactors = FALSE),
                               epochsize = 5, desiredtz = tz)
if (is.data.frame(sri)) {
  write.csv(data.frame(date = format(as.Date(sri$date, format = "%d/%m/%Y")),
                       sri = sprintf("%.17g", sri$SleepRegularityIndex),
                       frac_valid = sprintf("%.17g", sri$frac_valid)),
            paste0(out, ".sri.csv"), row.names = FALSE)
}
Lnames = c("spt_sleep", "spt_wake_IN", "spt_wake_LIG", "spt_wake_MOD", "spt_wake_VIG",
           "day_IN_unbt", "day_LIG_unbt", "day_MOD_unbt", "day_VIG_unbt",
           "day_MVPA_bts_10", "day_MVPA_bts_5_10", "day_MVPA_bts_1_5",
           "day_IN_bts_30", "day_IN_bts_20_30", "day_IN_bts_10_20",
           "day_LIG_bts_10", "day_LIG_bts_5_10", "day_LIG_bts_1_5")
res = list()
for (fragmode in c("day", "spt")) {  # g.part6.R:356-366
  lev = d$level
  lev[which(d$spt == ifelse(fragmode == "spt", 0, 1))] = NA
  fr = g.fragmentation(frag.metrics = "all", LEVELS = lev, Lnames = Lnames, xmin = 12,
                       mode = fragmode)
  for (k in names(fr)) res[[paste0(k, "_", fragmode)]] = num(fr[[k]])
}
write.csv(as.data.frame(res, check.names = FALSE), paste0(out, ".frag.csv"), row.names = FALSE)
