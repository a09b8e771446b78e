"""GGIR part 5's time-use rules and where each comes from (one place).

Source: wadpac/GGIR (Apache-2.0) at commit 388064b707df4fcfb7f9b755c5a43a477d371092, read for its
rules; stillpoint's code is its own.

==================================== ========================== ====================================
rule / constant                      value                      source
==================================== ========================== ====================================
sleep period (diur = 1)              onset to wake of each      R/g.part5.wakesleepwindows.R:151
                                     night, wake excluded
WW window                            a wake-up to the next      R/g.part5.definedays.R:122-132
                                     (epochs [wake_k, wake_k+1))
OO window                            an onset to the next       R/g.part5.definedays.R:122-132
time after the last wake / onset     no window                  R/g.part5.definedays.R:127-131
MM window                            local midnight to          R/g.part5.definedays.R:42-60
                                     midnight, first and last
                                     partial days included
                                     (shorter than 25 h)
spt sleep / spt wake                 SIB / no SIB inside the    R/identify_level.R:18-19
                                     sleep period
day (waking) band minutes            inactive < light <=        R/identify_level.R:26-37;
                                     light < moderate <= mod.   R/g.part5_analyseSegment.R:202-209
                                     < vigorous <= (totals:     (dur_day_total_*_min)
                                     OLEVELS)
default thresholds                   40 / 100 / 400 mg ENMO     R/load_params.R:109-110
sleep period classes                 spt_sleep: SIB; else       R/identify_level.R:16-24
                                     spt_wake_IN/LIG/MOD/VIG
                                     by the same edges
hierarchical bout classes            MVPA bouts (>= moderate)   R/identify_level.R:40-108
                                     first, then inactivity
                                     (< light), then light
                                     bouts, each kind longest
                                     first, each on the waking
                                     epochs no earlier bout
                                     took (refe == 0); an epoch
                                     in a bout leaves its
                                     unbouted class
bout lengths, longest first          MVPA 10, 5, 1 min; IN 30,  R/load_params.R:111-112;
                                     20, 10; LIG 10, 5, 1       R/g.part5.R:110-112 (sort)
bout criterion                       MVPA 0.8, IN 0.9, LIG 0.8  R/load_params.R:108-109
bout rule                            g.getbout over the whole   R/g.getbout.R; R/g.part5.R:434
                                     recording (bouts run       (identify_levels before the
                                     across window edges)       window loop)
class minutes per window             epochs of the class in     R/g.part5_analyseSegment.R:198-201
                                     the window x epoch / 60
dur_day_min, dur_spt_min,            waking / sleep-period /    R/g.part5_analyseSegment.R:210-215
dur_day_spt_min                      all epochs of the window
MM window without an onset and       the whole window counts    R/g.part5_analyseSegment.R:96-99,
without a wake-up                    as waking (dur_day_min,    454-458
                                     nonwear_perc_day, ...)
N_atleast5minwakenight               gaps of more than 5 min    R/g.part5_analyseSegment.R:218-220
                                     between spt_sleep epochs,
                                     minus 2, at least 0
sleep_efficiency_after_onset         SIB epochs of the sleep    R/g.part5_analyseSegment.R:224-225
                                     period / its epochs
Nbouts per bout class                runs of that class's       R/g.part5_analyseSegment.R:309-346
                                     g.getbout epochs inside
                                     the window
Nblocks per class                    runs of the class inside   R/g.part5_analyseSegment.R:349-361
                                     the window (and of the
                                     waking totals)
imputed nonwear                      part 5's ACC is part 2's   R/g.part5_initialise_ts.R:2-3, 23;
                                     imputed metashort: masked  R/g.impute.R (engine/outcomes/
                                     epochs count with their    impute.py); with --impute the
                                     imputed value              same, else missing (no class)
window of 15 min or less             not reported               R/g.part5.R:500
nonwear percentage of the day, of    nonwear epochs over the    R/g.part5_analyseSegment.R:148-162
the sleep period, of the window      part's epochs
window kept                          wear >= 2/3 of the waking  R/g.report.part5.R:20-23, 74-84;
                                     part; sleep period and     R/load_params.R:120
                                     waking part both present;
                                     MM: >= 23 h long           R/load_params.R:122
==================================== ========================== ====================================
"""

from __future__ import annotations

DEFAULT_THRESHOLDS_MG = (40.0, 100.0, 400.0)  # light, moderate, vigorous (ENMO)
INCLUDE_DAY_CRIT = 2.0 / 3.0
MINIMUM_MM_HOURS = 23.0
# bout kind -> (lengths in minutes, criterion), in GGIR's order of precedence
BOUT_CLASSES = {"MVPA": ((1, 5, 10), 0.8), "IN": ((10, 20, 30), 0.9), "LIG": ((1, 5, 10), 0.8)}
MINIMUM_WINDOW_S = 900.0  # a window must be longer than this to be reported
LONG_WAKE_S = 300.0  # N_atleast5minwakenight: gaps between sleep epochs longer than this
