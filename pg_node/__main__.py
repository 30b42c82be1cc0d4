"""Run ``python -m pg_node <command>``; see :mod:`pg_node.tools.cli`."""
import sys

from pg_node.tools.cli import main

if __name__ == '__main__':
    sys.exit(main())
