"""``python -m bench``: the benchmarks of :mod:`bench.suite`."""
import sys

from bench.suite import main

sys.exit(main())
