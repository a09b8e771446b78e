# Run GGIR's own rhythm functions on an epoch series written by
# tools/crosschecks/ggir_rhythm_fixtures.py and write what they compute.
# Usage: Rscript ggir_rhythm_fixtures.R GGIR_R_DIR ACTCR_R_FILE SERIES.csv TIMEZONE OUT_PREFIX
#   SERIES.csv: time_s (UTC seconds of the epoch start), local (GGIR's ISO 8601 with %z),
#   enmo_g (ENMO in g), invalid (0/1), midnight (0/1: the epoch starts at local midnight),
#   sib (0/1), class (1 inactive, 2 light, 3 MVPA; NA in the sleep period or invalid).
#   ACTCR_R_FILE: ActCR's ActCosinor / ActExtendCosinor (and cosinor.lm, correct.acrophase).
# Writes OUT_PREFIX.cosinor.csv (apply_cosinor_IS_IV_Analyses with epochsizes c(5, 5) and the
# light threshold 40 mg: one row), OUT_PREFIX.sri.csv (CalcSleepRegularityIndex on the SIBs, per
# day pair) and OUT_PREFIX.frag.csv (g.fragmentation's transition probabilities, mode "day").
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
  eval(parse(text = gsub("GGIR::", "", txt, fixed = TRUE)))
}
d = read.csv(series, colClasses = c("numeric", "character", "numeric", "numeric", "numeric",
                                    "numeric", "numeric"))
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
Lnames = c("day_IN_unbt", "day_LIG_unbt", "day_MOD_unbt")
fr = g.fragmentation(frag.metrics = "TP", LEVELS = d$class - 1, Lnames = Lnames, xmin = 12,
                     mode = "day")
write.csv(data.frame(TP_IN2PA = num(fr$TP_IN2PA), TP_PA2IN = num(fr$TP_PA2IN),
                     Nfrag_IN2PA = num(fr$Nfrag_IN2PA), Nfrag_PA2IN = num(fr$Nfrag_PA2IN)),
          paste0(out, ".frag.csv"), row.names = FALSE)
