"""The MCAP log of record: schemas, record encoding, chunk building, the one writer path, the
sink that turns pipeline outputs into messages, plus reading back (streaming, export, compare).

Public face (imported lazily)::

    from stillpoint.engine.mcap import McapLog, McapSink, CALIBRATION, QC, STATIC_CALIBRATION

Modules:
- ``log``: ``McapLog``, the one writer path (atomic ``.part`` output, topics, JSON/CDR messages);
- ``sink``: ``McapSink``, the pipeline's log: raw, corrected, view, temperature, epochs,
  estimates, QC;
- ``schemas``: the CDR message layouts of every topic and their encoders/decoders;
- ``jsonschemas``: the JSON schemas of the JSON topics;
- ``view``: the decimated, plottable view topic;
- ``records``: MCAP record encoders (opcodes, framing) per the MCAP specification;
- ``chunks``: one chunk's records and message indexes built from a block's messages;
- ``writer``: compresses chunks and writes the file (inline, thread or child process);
- ``stream``: flat-memory reads (topics in file order, metadata);
- ``export``: an MCAP log to CSV/NPZ;
- ``compare``: topic-by-topic comparison of two logs (``replay --check``).

This package is kept free of imports at load time so that the writer's child process
(``python -m stillpoint.engine.mcap.writer``) loads only the codec and the record encoders.
"""

_PUBLIC = {
    "McapLog": "log", "McapSink": "sink", "CALIBRATION": "jsonschemas", "QC": "jsonschemas",
    "STATIC_CALIBRATION": "jsonschemas", "ALIGNMENT_ESTIMATE": "jsonschemas",
    "ALIGNMENT_BLOCK_LAG": "jsonschemas", "JsonSchema": "jsonschemas",
}

__all__ = sorted(_PUBLIC)


def __getattr__(name):
    mod = _PUBLIC.get(name)
    if mod is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib
    return getattr(importlib.import_module(f"{__name__}.{mod}"), name)
