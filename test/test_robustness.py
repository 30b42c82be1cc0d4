"""``python -m pg_node robustness``: the sweep, its paired errors and its files."""
import csv
import json
import os
from pathlib import Path
import subprocess
import sys

import numpy as np
from pg_node.common.config_files import load_config
from pg_node.common.paths import default_config
from pg_node.rl.learner import Learner
from pg_node.tools import robustness
import pytest

REPO = Path(__file__).resolve().parent.parent


def test_summarise_pairs_each_point_with_the_nominal_episodes():
    rng = np.random.default_rng(0)
    grid = {'gear_scale': [0.5, 1.0], 'latency_steps': [0, 3]}
    base = rng.normal(-5, 2, 50)           # episodes differ a lot from each other...
    sweeps = []
    for shift in (0.0, 0.1):                # ... two seeds of a preset
        nominal = (base + shift, np.full(50, 0.01))
        sweeps.append({('gear_scale', 0.5): (base + shift - 1 + rng.normal(0, 0.1, 50),
                                             np.full(50, 0.03)),
                       ('gear_scale', 1.0): nominal, ('latency_steps', 0): nominal,
                       ('latency_steps', 3): (base + shift - 0.2, np.full(50, 0.01))})
    rows = {(r['axis'], r['value']): r for r in robustness.summarise(sweeps)}
    assert set(rows) == {(a, v) for a, vs in grid.items() for v in vs}
    weak = rows[('gear_scale', 0.5)]
    assert weak['episodes'] == 100 and weak['reached_share'] == 0.0
    # ... but the change is measured on the same episodes: its error is the noise's (0.1)
    assert weak['change_se'] == pytest.approx(0.1 / 10, rel=0.25)
    assert rows[('latency_steps', 3)]['change_se'] < 1e-12
    assert weak['final_distance_cm'] == pytest.approx(3.0)
    worst = robustness.worst(list(rows.values()))
    assert worst['gear_scale']['ratio'] == pytest.approx(3.0)
    assert worst['latency_steps']['ratio'] == pytest.approx(1.0)


@pytest.fixture(scope='module')
def two_runs(tmp_path_factory):
    """Two run directories, each with an untrained reacher2 policy of another seed."""
    runs = []
    for seed in (0, 1):
        root = tmp_path_factory.mktemp(f'seed{seed}') / 'run'
        sections = load_config(default_config(), [f'run_dir={root}', f'seed={seed}'])
        cfg = {k: v for section in sections.values() for k, v in section.items()}
        Learner(10, 2, cfg).save(root / 'checkpoints')
        runs.append(root)
    return runs


def test_sweep_writes_table_csv_json_and_plot(tmp_path, two_runs):
    out = tmp_path / 'out'
    env = dict(os.environ, PYTHONPATH=str(REPO))
    done = subprocess.run([sys.executable, '-m', 'pg_node', 'robustness', *map(str, two_runs),
                           '--episodes', '3', '--out', str(out)], env=env, cwd=REPO,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    # two runs of one name: named by their paths
    names = [str(p) for p in two_runs]
    assert all(f'### {n}' in done.stdout for n in names), done.stdout
    with open(out / 'robustness.csv') as f:
        rows = list(csv.DictReader(f))
    points = sum(len(v) for v in robustness.GRID.values())
    assert len(rows) == 2 * points
    mine = [r for r in rows if r['run'] == names[0]]
    by = {(r['axis'], float(r['value'])): r for r in mine}
    nominal = {r['return'] for r in mine if float(r['value']) == robustness.NOMINAL[r['axis']]}
    assert len(nominal) == 1                       # the one nominal evaluation, every axis
    assert by[('latency_steps', 3.0)]['return'] != by[('latency_steps', 0.0)]['return']
    assert by[('gear_scale', 0.6)]['return'] != by[('gear_scale', 1.0)]['return']
    data = json.loads((out / 'robustness.json').read_text())
    assert set(data) == set(names) and set(data[names[0]]['worst']) == set(robustness.GRID)
    from PIL import Image
    with Image.open(out / 'robustness.png') as img:
        assert img.size == (1920, 640)
        assert np.unique(np.asarray(img.convert('L'))).size > 10
