"""Options of `process` and `cohort run` for the activity outcome columns of the tables: a
cut-point set of the registry, GGIR bouts, Verisense steps (engine/outcomes)."""

from __future__ import annotations

import argparse

from ._numbers import number, number_list

BOUT_MINUTES = number_list(number(0, 1440, lo_open=True, unit="min"), increasing=True,
                           what="increasing minutes")
CRITERION = number(0, 1, lo_open=True)


def cutpoint_key(text: str) -> str:
    """An argparse ``type``: a key of the cut-point registry."""
    from stillpoint.engine.outcomes.cutpoints import lookup
    try:
        return lookup(text).key
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def step_sets(text: str) -> tuple:
    """An argparse ``type``: Verisense parameter sets, comma-separated."""
    from stillpoint.engine.outcomes.verisense import PARAMETER_SETS
    names = tuple(x.strip() for x in text.split(",") if x.strip())
    bad = [x for x in names if x not in PARAMETER_SETS]
    if not names or bad:
        raise argparse.ArgumentTypeError(
            f"{text!r}: Verisense parameter sets are {', '.join(PARAMETER_SETS)}")
    return names


def add_outcome_arguments(p) -> None:
    g = p.add_argument_group("activity outcomes (docs/activity-outcomes.md)")
    g.add_argument("--cutpoints", type=cutpoint_key, default=None, metavar="KEY",
                   help="a cut-point set of the registry (e.g. hildebrand_adults_geneactiv_wrist): "
                        "minutes and GGIR bouts per band in the day table, each epoch's band in "
                        "the epoch table; columns carry the key")
    g.add_argument("--bout-minutes", type=BOUT_MINUTES, default=(1.0, 5.0, 10.0), metavar="MIN,...",
                   help="GGIR bout lengths in minutes for --cutpoints (default 1,5,10)")
    g.add_argument("--bout-criterion", type=CRITERION, default=0.8, metavar="F",
                   help="share of a bout's epochs that must meet the band (GGIR boutcriter, "
                        "default 0.8)")
    g.add_argument("--steps", action="store_true",
                   help="count steps with the Verisense algorithm (parameter sets: --step-sets)")
    g.add_argument("--step-sets", type=step_sets, default=("original", "rowlands2022"),
                   metavar="SET,...",
                   help="the Verisense parameter sets for --steps (default: both, "
                        "original,rowlands2022)")
    g.add_argument("--impute", action="store_true",
                   help="also give day values on epochs where nonwear (and every other flagged "
                        "epoch) is replaced by the same time of day's mean over the other days, "
                        "as GGIR's g.impute does: columns ending _imputed")


def outcome_settings(args):
    from stillpoint.engine.outcomes.daily import OutcomeSettings
    steps = tuple(args.step_sets) if args.steps else ()
    return OutcomeSettings(cutpoints=args.cutpoints or "",
                           bout_minutes=tuple(float(x) for x in args.bout_minutes),
                           bout_criterion=float(args.bout_criterion), steps=tuple(steps),
                           impute=bool(getattr(args, "impute", False)))
