"""
Checkpoints that cannot be half-written, and resuming from the newest valid one.

A checkpoint is written to a temporary file in the same directory, flushed and fsynced, then
renamed over its final name (``os.replace`` is atomic on POSIX): a crash leaves either the
old set of files or the new one, never a torn file. On resume the newest checkpoint that
loads is used; one that does not (truncated, corrupted) is reported and skipped.
"""
import logging
import os
from pathlib import Path
import tempfile
from typing import List, Optional, Tuple

from pg_node.common.run_dir import CHECKPOINT_NAME, CHECKPOINT_PATTERN
import torch

log = logging.getLogger(__name__)


def checkpoint_path(directory, version: int) -> Path:
    """Return the file name of the checkpoint of policy ``version``."""
    return Path(directory) / CHECKPOINT_NAME.format(version)


def save_checkpoint(directory, version: int, state: dict, keep: int = 3) -> Path:
    """Atomically write ``state`` as the checkpoint of ``version``; keep the newest ``keep``."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    final = checkpoint_path(directory, version)
    fd, tmp = tempfile.mkstemp(prefix='.ckpt_', suffix='.tmp', dir=directory)
    try:
        with os.fdopen(fd, 'wb') as f:
            torch.save({'version': int(version), **state}, f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, final)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    dir_fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)
    if keep > 0:
        for old, _ in list_checkpoints(directory)[keep:]:
            old.unlink(missing_ok=True)
    return final


def list_checkpoints(directory) -> List[Tuple[Path, int]]:
    """Return ``[(path, version), ...]`` in the directory, newest first."""
    directory = Path(directory)
    if not directory.is_dir():
        return []
    found = [(p, int(m.group(1))) for p in directory.iterdir()
             if (m := CHECKPOINT_PATTERN.match(p.name))]
    return sorted(found, key=lambda pv: pv[1], reverse=True)


def load_latest(directory) -> Tuple[Optional[dict], List[str]]:
    """
    Return ``(state, problems)``: the newest checkpoint that loads, and what was skipped.

    ``state`` is None when there is no loadable checkpoint; ``problems`` holds one message
    per checkpoint file that could not be read.
    """
    problems = []
    for path, version in list_checkpoints(directory):
        try:
            state = torch.load(path, map_location='cpu', weights_only=False)
            if not isinstance(state, dict) or state.get('version') != version:
                raise ValueError('content does not match its file name')
            return state, problems
        except Exception as exc:  # noqa: B902 - any unreadable file is skipped, not fatal
            msg = f'skipping unreadable checkpoint {path}: {exc}'
            log.warning(msg)
            problems.append(msg)
    return None, problems
