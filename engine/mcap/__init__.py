"""The MCAP log of record: schemas, record encoding, chunk building, the writer and the sink
that turns pipeline outputs into messages, plus reading back (export, compare).

Modules:
- ``schemas``: the CDR message layouts of every topic and their encoders/decoders;
- ``records``: MCAP record encoders (opcodes, framing) per the MCAP specification;
- ``chunks``: one chunk's records built from a block's messages;
- ``writer``: compresses chunks and writes the file (inline, thread or child process);
- ``sink``: the pipeline's sink: raw, corrected, temperature, epochs, estimates, QC;
- ``export``: an MCAP log to CSV/NPZ;
- ``compare``: topic-by-topic comparison of two logs (``replay --check``).

This package is kept free of imports at load time so that the writer's child process
(``python -m stillpoint.engine.mcap.writer``) loads only numpy and the codec.
"""
