"""Activity outcomes: the cut-point registry (``cutpoints``), time in intensity bands and GGIR's
bouts per band (``bands``, ``bouts``), and step counts with the Verisense algorithm
(``verisense``, ``steps``)."""
