"""Cross-checks: scripts that compare stillpoint's results with the truth of simulated
recordings, with peers' outputs or with the same run another way (see each docstring)."""
