"""``python -m bench``: the benchmarks of :mod:`bench.suite`; ``python -m bench tax``: ratio."""
import sys

if sys.argv[1:2] == ['tax']:
    from bench.tax import main
    sys.exit(main(sys.argv[2:]))

from bench.suite import main  # noqa: E402

sys.exit(main())
