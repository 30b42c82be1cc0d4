"""Run ``python -m pg_node <command>``; see :mod:`pg_node.cli`."""
import sys

from pg_node.cli import main

if __name__ == '__main__':
    sys.exit(main())
