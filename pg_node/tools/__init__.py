"""
The tools layer: ``python -m pg_node <command>`` and what the commands share.

``cli`` dispatches; ``train`` (with ``processes``) brings the graph up and supervises it;
``evaluate``, ``variance``, ``monitor``, ``topics``, ``plot``, ``render``, ``reindex``,
``export`` and ``play`` are one command each. The benchmarks and the soak are not part of the
package: they are the repository's ``bench`` package (``python -m bench``).
"""
