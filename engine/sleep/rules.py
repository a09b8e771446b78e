"""The sleep rules' constants and where each comes from (one place).

Source: wadpac/GGIR (Apache-2.0) at commit 388064b707df4fcfb7f9b755c5a43a477d371092, read for its
rules; stillpoint's code is its own. Papers: van Hees et al. 2015, PLoS ONE 10(11):e0142533
(sustained inactivity bouts); van Hees et al. 2018, Sci Rep 8:12975 (HDCZA; the C-statistics
0.86 / 0.83 quoted in docs/sleep.md are that paper's, not ours).

==================================== ========================== ====================================
rule / constant                      value                      source
==================================== ========================== ====================================
SIB posture change                   |diff(anglez)| > 5 deg     R/HASIB.R:54; R/load_params.R:14
SIB: changes less than once per      5 min (60 epochs of 5 s)   R/HASIB.R:58; R/load_params.R:14
SIB interval [change, next change]   both ends included         R/HASIB.R:62
SIB fallback (no 5-min gap at all)   all 1 if < 10 changes      R/HASIB.R:64-69
                                     else all 0
anglez NA (gap) taken as 0           -                          R/g.sib.det.R:73-80
HDCZA x: rolling median of           5 min window (60 epochs),  R/HASPT.R:106-113 (zoo centre
|diff(anglez)|                       offsets -29..+30, edges 0  alignment: offsets seq(to=floor(w/2)))
HDCZA threshold                      10th percentile x 15,      R/HASPT.R:114-126 (quantile type 7)
                                     clamped to [0.13, 0.50]
HDCZA options: HDCZA_threshold,      defaults c(10, 15) /       R/load_params.R:19,30,39-41
HASPT.ignore.invalid,                FALSE / 30 min / 60 min /
spt_min_block_dur, spt_max_gap_dur,  1
spt_max_gap_ratio
nonwear as no-movement (NA) or       ignore_invalid            R/HASPT.R:365-372
movement (TRUE); "+invalid" guider                              R/HASPT.R:445-459
blocks <= 30 min dropped; gaps       padded with one 0 each     R/HASPT.R:380-418; rebuild_rle
< 60 min filled; longest block kept  side; after an edit the    R/HASPT.R:94-99 (y[1:N])
(first of equal)                     sequence is cut to N
SPTE_start / SPTE_end                first / one past last      R/HASPT.R:419-432
                                     index of the kept block
night window                         midnight - 12 h + 1 epoch  R/g.sib.det.R:241-261
                                     .. midnight + 12 h; 11/13
                                     o'clock end moved 1 h (DST)
first night (recording starts        [first epoch, first noon]  R/g.sib.det.R:207-220, 242-244
00:00-04:00)
no midnight in the recording         last epoch as midnight     R/g.detecmidnight.R:22-25
recording shorter than 0.2 day       no sleep detection         R/g.sib.det.R:68-69
daysleeper: SPT ends within 1 h of   re-run on the window       R/g.sib.det.R:314-364
noon                                 moved 6 h, kept if it ends
                                     after noon
guider order                         sleeplog, HDCZA, L5 +- 6 h R/g.part4.R:336-404, 420-490
sleep-log daysleeper                 wake > 12 and onset < 12,  R/g.part4.R:476-481
                                     or wake > 12 and onset >
                                     wake; wake 12-18 next day
night onset / wake                   first / last SIB that      R/g.part4.R:688-720
                                     overlaps the guider window
no SIB overlapping the guider        rely on the guider         R/g.part4.R:652-686
L5 for the L5 +- 6 h guider          5 h rolling mean of ENMO,  R/g.sib.det.R:274-290
                                     odd window, first minimum
night fraction invalid               (invalid + epochs missing  R/g.sib.sum.R:71-74
                                     from 24 h) / 24 h, <= 1
cleaningcode                         0 sleeplog, 1 none, 5 no   R/g.part4.R:433,488,495,
                                     SIB overlaps the guider,   661-665, 881-885
                                     2 fraction invalid > (24 -
                                     includenightcrit) / 24
includenightcrit                     16 h                       R/load_params.R:124
cleaned nights (part 4 "cleaned")    cleaningcode <= 1          R/g.report.part4.R:193
sleep-log formats                    basic: ID, onset, wakeup   R/create_test_sleeplog_csv.R:11-29
                                     pairs per night; advanced: ,44-66
                                     ID, Dn_date, Dn_wakeup,
                                     Dn_onset ...
==================================== ========================== ====================================
"""

from __future__ import annotations

EPOCH_S = 5.0
ANGLE_THRESHOLD_DEG = 5.0
TIME_THRESHOLD_MIN = 5.0
FALLBACK_MAX_CHANGES = 10
HDCZA_WINDOW_MIN = 5.0
HDCZA_THRESHOLD = (10.0, 15.0)  # percentile, multiplier
HDCZA_CLAMP = (0.13, 0.50)
SPT_MIN_BLOCK_MIN = 30.0
SPT_MAX_GAP_MIN = 60.0
SPT_MAX_GAP_RATIO = 1.0
DAYSLEEP_OFFSET_H = 6
DAYSLEEP_NEAR_NOON_H = 1
MIN_NIGHT_EPOCHS = 60
MIN_RECORDING_DAYS = 0.2
L5_HOURS = 5
L5_HALF_WINDOW_H = 6
INCLUDE_NIGHT_CRIT_H = 16.0
VALID_CLEANINGCODE_MAX = 1
