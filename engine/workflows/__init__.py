"""Workflows built on the engine. ``discrepancy``: where a sensor model and a measurement disagree,
which named effect is missing, and how much adding it shrinks the held-out gap.

Modules: ``api`` (``analyse``: input + model -> report), ``discrepancy`` (the loop), ``sensor_fit``
(the model and its robust fit), ``candidates`` (the effect library), ``locate`` (residual by
covariate, distribution checks), ``inputs``/``sources`` (feature tables, recordings, MCAP logs),
``simmodel`` (the simulator's JSON), ``report`` (JSON, text, PNG), ``simwindows`` (window
features from the simulator's wearer, temperature and sensor model, without a file) and
``scenarios`` (the hidden-effect scenarios of the tests and the 20-seed table).
``tables_from_mcap``: the epoch and day tables of a logged run, from its MCAP.
"""


def analyse(*args, **kwargs):
    """See ``stillpoint.engine.workflows.api.analyse``."""
    from .api import analyse as _analyse
    return _analyse(*args, **kwargs)


__all__ = ["analyse"]
