"""The pipeline's core: ``blocks`` (the Block every stage passes on), ``source`` (readers as
block sources), ``ringbuffer`` and ``pipeline`` (the bounded operator chain), ``prefetch``
(reading ahead on a thread), ``cache``, ``kernels`` (shared numpy kernels), ``malloc``
(the allocator's thresholds), ``jsonsafe`` (JSON of estimates and summaries) and ``times`` (ISO
instants and UTC offsets as text). Nothing here imports another part of the project."""
