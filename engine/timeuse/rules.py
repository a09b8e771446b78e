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
                                     light < moderate <= mod.   R/g.part5_analyseSegment.R:198-208
                                     < vigorous <=
default thresholds                   40 / 100 / 400 mg ENMO     R/load_params.R:109-110
bouts per band                       g.getbout (80 %; 1, 5, 10  R/g.getbout.R; R/load_params.R:
                                     min)                       107-112
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
BOUT_MINUTES = (1, 5, 10)
