"""The Makefile installs when requirements.lock or setup.py change, and only then (issue 33)."""
import os
from pathlib import Path
import shutil
import subprocess
import time

import pytest

REPO = Path(__file__).resolve().parent.parent


def _plan(tmp: Path) -> str:
    """Return what ``make venv`` would run in ``tmp`` (``make -n``: nothing is run)."""
    done = subprocess.run(['make', '-n', 'venv'], cwd=tmp, capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stderr
    return done.stdout


@pytest.fixture
def checkout(tmp_path):
    """Return a directory with the Makefile, its inputs and an installed .venv's stamp."""
    if shutil.which('make') is None:
        pytest.fail('make is not installed: the README runs everything through it')
    for name in ('Makefile', 'requirements.lock', 'setup.py'):
        shutil.copy(REPO / name, tmp_path / name)
    first = _plan(tmp_path)
    assert 'pip install' in first       # no .venv yet: everything is installed
    stamp = next(ln for ln in first.splitlines() if ln.startswith('touch ')).split()[1]
    (tmp_path / stamp).parent.mkdir(parents=True)
    (tmp_path / stamp).touch()
    assert 'pip install' not in _plan(tmp_path)
    return tmp_path


def test_new_dates_with_the_same_content_install_nothing(checkout):
    later = time.time() + 60        # what a clone, checkout or copy does to the dates
    for name in ('requirements.lock', 'setup.py'):
        os.utime(checkout / name, (later, later))
    assert 'pip install' not in _plan(checkout)


def test_a_changed_lock_installs_again(checkout):
    with open(checkout / 'requirements.lock', 'a') as f:
        f.write('\n# changed\n')
    assert 'pip install' in _plan(checkout)
