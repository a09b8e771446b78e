"""The rhythm rules' constants and where each comes from (one place).

Source: wadpac/GGIR (Apache-2.0) at commit 388064b707df4fcfb7f9b755c5a43a477d371092 and ActCR
0.3.0 (Junrui Di et al., GPL-3; the version GGIR 3.x imports, whose ``ActExtendCosinor`` takes
``export_ts``), with cosinor's ``cosinor.lm`` and cosinor2's ``correct.acrophase``; read for their
rules, stillpoint's code is its own. Papers: Witting et al. 1990 (IS, IV); Danilevicz et al. 2024
(IS/IV on the series binarised at the light threshold, GGIR 3.1-6); Cornelissen 2014 (cosinor);
Marler et al. 2006 (extended cosinor); van Someren et al. 1999 (RA from M10 and L5); Phillips et
al. 2017 (SRI); Di et al. 2017 (transition probabilities).

==================================== ========================== ====================================
rule / constant                      value                      source
==================================== ========================== ====================================
invalid epochs missing, hour of NA   02:00 + 1 epoch on the     R/apply_cosinor_IS_IV_Analyses.R:7-35
inserted on the first day whose      first short/long day;
midnights are not 24 h apart; start  start at first valid
trimmed to the first valid epoch     epoch
more than 24 h of valid epochs       else no cosinor, IS, IV    R/apply_cosinor_IS_IV_Analyses.R:36
time offset                          hours from the first valid R/apply_cosinor_IS_IV_Analyses.R:37-38
                                     epoch to the next midnight
minute means of 12 epochs            NA when none valid         R/apply_cosinor_IS_IV_Analyses.R:39-58
whole days; trailing empty days      dropped                    R/cosinor_IS_IV_Analyses.R:7-19
dropped
g to mg when max < 13 and mean < 1   x 1000                     R/cosinor_IS_IV_Analyses.R:20-28
cosinor on log(mg + 1)               ActCosinor, window 1 min   R/cosinor_IS_IV_Analyses.R:29-32
extended cosinor                     ActExtendCosinor           R/cosinor_IS_IV_Analyses.R:35
acrophase / up / down mesor times    minus the offset, + 24 if  R/cosinor_IS_IV_Analyses.R:36-50
                                     negative; radians likewise
R2                                   cor(observed, fitted)^2    R/cosinor_IS_IV_Analyses.R:56-57
IS / IV input                        the mg minute series       R/cosinor_IS_IV_Analyses.R:52-54
light threshold (binarise, part 2)   threshold.lig 40 mg        R/g.analyse.avday.R:119-122;
                                                                R/load_params.R:109
binarised: > threshold 0, else 1     NA stays NA                R/g.IVIS.R:2-4
hourly means from the first value    NA left out                R/g.IVIS.R:5-13
IS = N sum(Xh - Xm)^2 /              Xh: mean per hour of day,  R/g.IVIS.R:19-36
  (24 sum(Xi - Xm)^2)                Xm: their mean
IV = N sum(diff Xi)^2 /              N: hours with a value      R/g.IVIS.R:26-41
  ((N - 1) sum(Xi - Xm)^2)
phi                                  arima(order = c(1,0,0))    R/g.IVIS.R:29-31
                                     on the non-missing hours
cosinor: lm(Y ~ cos + sin), 24 h,    t = (1..1440) / 60 h per   ActCR R/ActCosinor.R; cosinor
amp = hypot, acrophase by signs      day                        R/cosinor.lm.R; cosinor2
                                                                correct.acrophase
extended cosinor start, bounds       (max(mes - amp, 0), 2 amp, ActCR R/ActExtendCosinor.R
                                     0, 2, acrotime);
                                     lower (0, 0, -1, 0, -3),
                                     upper (Inf, Inf, 1, Inf, 27)
up / down mesor, MESOR, F pseudo     phi -/+ acos(alpha) 24 /   ActCR R/ActExtendCosinor.R
                                     2 pi; min + amp / 2
M10 / L5 of the average day          the imputation's average   R/g.analyse.avday.R:60-70, 99;
                                     day from the first         R/g.getM5L5.R:14-31
                                     midnight, windows every
                                     10 min
SRI: 30-s means rounded, per pair    -100 + 200 x same / valid  R/CalcSleepRegularityIndex.R:26-101
of local dates                       slots; 25 h days cut to 24
SRI input (part 3)                   the SIBs, nonwear missing  R/g.part3.R:105-118
SRI day pairs kept                   frac_valid > 16 / 24       R/g.part4.R:1136
transition probabilities             (N + 1e-6) / (duration -   R/g.fragmentation.R:21-92
                                     last runs + 1e-6), 6 dp
fragmentation classes                part 5's classes (bouts    R/g.part6.R:356-362;
                                     included): IN, LIG, MVPA   R/g.fragmentation.R:100-126
                                     in the waking part; the
                                     sleep period missing
                                     ("day" mode), the waking
                                     part missing ("spt" mode)
mean fragment durations              epochs of the runs         R/g.fragmentation.R:64-67, 146,
                                     followed by the other      150, 188-191
                                     class / their number
NFragPM                              fragments / those epochs   R/g.fragmentation.R:192-198
SD, Gini, CoV, power law             on the binary series       R/g.fragmentation.R:199-234;
                                     (inactivity or not), with  ineq 0.2-13 R/ineq.R (Gini,
                                     at least 10 fragments:     corr = TRUE); Chastin et al.
                                     Gini with n - 1; CoV: sd   2010 (alpha, x0.5, W0.5)
                                     over mean of the log
                                     durations; alpha: 1 + n /
                                     sum(log(d / xmin)), xmin
                                     1 min; x0.5: 2^(xmin /
                                     (alpha - 1)); W0.5: share
                                     of time in fragments
                                     longer than x0.5
==================================== ========================== ====================================
"""

from __future__ import annotations

LIGHT_MG = 40.0
MODERATE_MG = 100.0  # part 6's thresholds: GGIR's defaults (R/load_params.R:109-110)
VIGOROUS_MG = 400.0
MINUTES_PER_DAY = 1440
EXT_LOWER = (0.0, 0.0, -1.0, 0.0, -3.0)
EXT_UPPER = (float("inf"), float("inf"), 1.0, float("inf"), 27.0)
M_STEP_S = 600.0
SRI_MIN_FRAC_VALID = 16.0 / 24.0
