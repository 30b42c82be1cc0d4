"""
The tools layer: ``python -m pg_node <command>`` and what the commands share.

``cli`` dispatches; ``train`` (with ``processes``) brings the graph up and supervises it;
``evaluate``, ``variance``, ``bench`` (``bench_runs``, ``latency_probe``), ``soak``,
``monitor``, ``topics``, ``plot``, ``render``, ``reindex``, ``export`` and ``play`` are one
command each.
"""
