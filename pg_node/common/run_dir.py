"""
A training run's directory: what lives where in it, and how its files are written and read.

``python -m pg_node train`` (and the learner it starts) writes, under ``run_dir``:

* ``params.yaml``: the resolved parameters of every node (``params_arm<i>.yaml`` beside it
  for each simulator/actor pair of several);
* ``progress.csv``: one row per update, written by the learner (:class:`ProgressWriter`)
  while ``train``'s progress bar, its summary, ``plot`` and the benchmarks read it
  (:func:`read_progress`, :func:`last_progress`);
* ``bag/``, then ``bag_1/``, ``bag_2/``... : the episodes learned from, a new bag for each
  learner start after the first (a restart, or a run resumed by a second ``train``);
* ``checkpoints/``: ``ckpt_<version>.pt``, the newest valid one resumed;
* ``tensorboard/``, ``logs/<process>.log``, ``summary.json`` (strict JSON,
  :meth:`RunDir.write_summary`) and ``learning_curve.png``.

Every module that writes or reads one of these goes through :class:`RunDir`, so that a name
or a format is decided here once. Standard library only: the learner, the tools and the
benchmarks all use it.
"""
import csv
import json
import math
import os
from pathlib import Path
import re
from typing import Dict, List, Optional, Sequence

#: a policy checkpoint's file name, by its version (:mod:`pg_node.rl.checkpoint`)
CHECKPOINT_NAME = 'ckpt_{:08d}.pt'
#: what a checkpoint's file name matches; its group is the version
CHECKPOINT_PATTERN = re.compile(r'^ckpt_(\d{8})\.pt$')
#: the first bag's folder; the next learner start writes ``bag_1``, then ``bag_2``...
BAG = 'bag'
#: the folder of the learner's checkpoints
CHECKPOINTS = 'checkpoints'


def progress_rows(lines: Sequence[str]) -> List[Dict[str, float]]:
    """
    Parse ``progress.csv`` lines (header first) into dicts of floats, empty cells NaN.

    A last line without its newline is not finished (the learner is writing it) and is left
    out, whatever it holds so far.
    """
    if lines and not lines[-1].endswith('\n'):
        lines = lines[:-1]
    return [{k: float(v) if v not in ('', None) else float('nan') for k, v in r.items()}
            for r in csv.DictReader(lines)]


def read_progress(path, since: int = 0) -> List[Dict[str, float]]:
    """
    Return the finished rows of the progress file ``path`` (none: ``[]``).

    ``since``: a byte offset; only the rows written from there on (a session's own, when it
    is the file's size at the session's start).
    """
    try:
        with open(path, 'rb') as f:
            header = f.readline()
            f.seek(max(since, f.tell()))
            tail = f.read()
    except OSError:
        return []
    return progress_rows([header.decode(errors='replace')]
                         + tail.decode(errors='replace').splitlines(keepends=True))


def last_progress(path, tail_bytes: int = 8192) -> Optional[Dict[str, float]]:
    """
    Return the newest finished row of the progress file ``path`` (None if none yet).

    Reads the header and the last ``tail_bytes`` only: a watcher polls this while a long
    run's file grows by a row per update.
    """
    try:
        with open(path, 'rb') as f:
            header = f.readline().decode(errors='replace')
            start = max(f.tell(), f.seek(0, os.SEEK_END) - tail_bytes)
            f.seek(start)
            lines = f.read().decode(errors='replace').splitlines(keepends=True)
    except OSError:
        return None
    if start > len(header):
        lines = lines[1:]       # the tail began inside a row
    rows = progress_rows([header] + lines)
    return rows[-1] if rows else None


class ProgressWriter:
    """
    Appends rows to a progress file, its header first when the file is new.

    A NaN is written as an empty cell (no episode finished yet, say) and ``wall_seconds`` to
    the millisecond; rows reach the disk at :meth:`flush`, which the learner calls once a
    second and at every checkpoint.
    """

    def __init__(self, path, fields: Sequence[str]):
        path = Path(path)
        new = not path.exists()
        self.file = open(path, 'a', newline='')
        self.writer = csv.DictWriter(self.file, fields)
        if new:
            self.writer.writeheader()

    def write(self, wall_seconds: float, metrics: Dict[str, float]) -> None:
        """Add the row of one update: the run's training time and the update's metrics."""
        self.writer.writerow({'wall_seconds': round(wall_seconds, 3),
                              **{k: ('' if isinstance(v, float) and math.isnan(v) else v)
                                 for k, v in metrics.items()}})

    def flush(self) -> None:
        """Put the rows written so far on disk, for the readers."""
        self.file.flush()

    def close(self) -> None:
        """Flush and close the file."""
        self.file.close()


def strict_json(value):
    """
    Return ``value`` with every NaN or infinity replaced by None, for strict JSON (``null``).

    ``json.dumps`` writes ``NaN``, which JSON does not have: ``jq`` and most other readers
    refuse the file. A curve's return before any episode ended is such a value.

    >>> strict_json({'curve': [{'r': float('nan')}, {'r': -4.5}], 'n': 3})
    {'curve': [{'r': None}, {'r': -4.5}], 'n': 3}
    """
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: strict_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [strict_json(v) for v in value]
    return value


class RunDir:
    """
    The layout of one run's directory, and its files' writers and readers.

    Nothing is created by building one: :meth:`make` creates the directory.
    """

    def __init__(self, path):
        self.path = Path(path)
        self.params = self.path / 'params.yaml'         # every node's resolved parameters
        self.bag = self.path / BAG                      # the first bag (then bag_1, ...)
        self.progress = self.path / 'progress.csv'      # the learner's row per update
        self.checkpoints = self.path / CHECKPOINTS      # the learner's ckpt_<version>.pt
        self.summary = self.path / 'summary.json'       # train's summary of the run
        self.logs = self.path / 'logs'                  # the node processes' logs
        self.tensorboard = self.path / 'tensorboard'    # the learner's event files
        self.curve = self.path / 'learning_curve.png'   # the figure train draws at the end

    @classmethod
    def of_checkpoint(cls, path) -> 'RunDir':
        """
        Return the run that ``path`` names: the run's directory, or its checkpoints in it.

        ``<run>``, ``<run>/checkpoints`` and ``<run>/checkpoints/ckpt_*.pt`` all name
        ``<run>`` (resolved: ``.`` has a name too).
        """
        path = Path(path).resolve()
        if path.suffix == '.pt':
            path = path.parent.parent
        elif path.name == CHECKPOINTS:
            path = path.parent
        return cls(path)

    def __repr__(self):
        return f'RunDir({str(self.path)!r})'

    def log(self, process: str) -> Path:
        """Return the log file of the node process named ``process``."""
        return self.logs / f'{process}.log'

    def make(self) -> 'RunDir':
        """Create the directory (and its parents) if it does not exist; return self."""
        self.path.mkdir(parents=True, exist_ok=True)
        return self

    def has_bag(self) -> bool:
        """Return whether the run has its first bag: whether ``path`` is a run directory."""
        return self.bag.is_dir()

    def bags(self) -> List[Path]:
        """
        Return the run's bags in the order its learners wrote them: ``bag``, ``bag_1``...

        A learner that restarts, or a run resumed by a second ``train``, writes the next one.
        """
        found = [p for p in self.path.glob(f'{BAG}*')
                 if p.is_dir() and _bag_index(p.name) is not None]
        return sorted(found, key=lambda p: _bag_index(p.name))

    def next_bag(self) -> Path:
        """Return the folder of the bag a learner starting now writes: the first free name."""
        if not self.bag.exists():
            return self.bag
        k = 1
        while (self.path / f'{BAG}_{k}').exists():
            k += 1
        return self.path / f'{BAG}_{k}'

    def has_checkpoint(self) -> bool:
        """Return whether ``checkpoints/`` holds a checkpoint file (readable or not)."""
        return (self.checkpoints.is_dir()
                and any(CHECKPOINT_PATTERN.match(p.name) for p in self.checkpoints.iterdir()))

    def progress_writer(self, fields: Sequence[str]) -> ProgressWriter:
        """Return a writer appending rows of ``fields`` to ``progress.csv``."""
        return ProgressWriter(self.progress, fields)

    def read_progress(self, since: int = 0) -> List[Dict[str, float]]:
        """Return the finished rows of ``progress.csv`` (see :func:`read_progress`)."""
        return read_progress(self.progress, since)

    def last_progress(self, tail_bytes: int = 8192) -> Optional[Dict[str, float]]:
        """Return the newest finished row of ``progress.csv`` (None if none yet)."""
        return last_progress(self.progress, tail_bytes)

    def write_summary(self, summary: dict) -> None:
        """Write ``summary.json`` as strict JSON (no NaN: ``null``)."""
        self.summary.write_text(json.dumps(strict_json(summary), indent=2, default=str,
                                           allow_nan=False))

    def read_summary(self) -> Optional[dict]:
        """Return ``summary.json`` (None when the run has none)."""
        if not self.summary.is_file():
            return None
        return json.loads(self.summary.read_text())


def _bag_index(name: str) -> Optional[int]:
    """
    Return the place of a bag folder in its run (``bag`` 0, ``bag_3`` 3), None for another name.

    >>> [_bag_index(n) for n in ('bag', 'bag_12', 'bag_', 'bags', 'bag_x1')]
    [0, 12, None, None, None]
    """
    if name == BAG:
        return 0
    head, sep, tail = name.partition('_')
    return int(tail) if head == BAG and sep and tail.isdigit() else None
