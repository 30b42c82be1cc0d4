"""
pg_node's benchmarks and soak: measurement and fault injection, not part of the package.

A plain Python package of the repository, never installed (``setup.py`` installs
``pg_node`` alone), run from the repository root (``make`` puts it on ``PYTHONPATH``):

* ``python -m bench`` (:mod:`bench.suite`, ``make bench``, ``make bench-quick``,
  ``make profile``): throughput, latency, learning and estimator-variance benchmarks, written
  to ``docs/results/`` (BENCHMARKS.md, PROFILE.md and their plots);
* ``python -m bench.soak``: training with faults injected on a schedule, and a report;
* the modules the two share with the tests: :mod:`bench.runs` (the measurements),
  :mod:`bench.tax`, :mod:`bench.curves`, :mod:`bench.pool`, :mod:`bench.latency_probe` and
  :mod:`bench.lan` (network namespaces as hosts, root only);
* ``bench/bench_*.py`` and the other scripts: one-off probes behind a table of BENCHMARKS.md
  or PROFILE.md, each run as ``python bench/<script>.py`` and described in its docstring.
"""
