"""
An arm the recipe was not tuned on learns to reach from what ``arm import`` chose (issue 55).

pybullet_data's KUKA iiwa (``kuka_iiwa/model.urdf``: 300 N m on every joint, a 0.3 kg last
link; the torque recipe was measured on the Panda) is imported with nothing but ``--tip``:
the start pose, the goal region, hard limits, the effort caps, the armature and the
timestep are the import's. It is trained in process with the printed command's arguments
(the recipe's randomization and frame_skip) for a short budget, and the deterministic
policy must end clearly closer to its goals than standing still does. A regression of the
choices (a start pose at a singularity or a limit, goals out of reach, physics that
diverge under the recipe) fails it.

The budget shows learning, not the result (BENCHMARKS.md, "Arms nobody tuned"): 100k
steps on 16 arms, with a smaller starting noise (``log_std_init`` -1.5), control cost
(``reward_control_weight`` 0.1) and a larger learning rate than the preset's, so that the
policy starts reaching within it. Seen (seed 0, 2026-12-07): 0.198 m against 0.289 m
standing still; 37 s on a quiet machine, 80 s at load 7.
"""
from pathlib import Path
import shlex

import numpy as np
from pg_node.common.config_files import load_config
from pg_node.common.paths import config_file
from pg_node.rl.evaluate import evaluate_policy
from pg_node.rl.train_inprocess import train_inprocess
from pg_node.tools import arm
import pytest
import torch

#: what shortens the budget to one that shows learning (the module's docstring says why)
SHORT = ['num_envs=16', 'log_std_init=-1.5', 'reward_control_weight=0.1',
         'learning_rate=0.001']


class StandStill:
    """A policy that commands nothing: the arm stays where it starts."""

    def __init__(self, act_dim: int):
        self.act_dim = act_dim

    def mean_action(self, obs):
        """Return zero commands."""
        return torch.zeros(obs.shape[0], self.act_dim)


def printed_overrides(stdout: str):
    """Return the one printed train command's preset and its ``key=value`` arguments."""
    line = next(line for line in stdout.splitlines() if line.startswith('train with: '))
    argv = shlex.split(line.partition('train with: ')[2].partition('  (')[0])
    assert argv[:5] == ['python', '-m', 'pg_node', 'train', '--config']
    return argv[5], [a.replace(':=', '=', 1) for a in argv[6:]]


def test_an_arm_nobody_tuned_learns_to_reach_from_the_import(tmp_path, capsys):
    pybullet_data = pytest.importorskip('pybullet_data')
    urdf = Path(pybullet_data.getDataPath()) / 'kuka_iiwa' / 'model.urdf'
    out = tmp_path / 'iiwa.xml'
    code = arm.main(['import', str(urdf), '--tip', 'lbr_iiwa_link_7', '--targets', '200',
                     '--no-visual-meshes', '-o', str(out)])
    stdout, err = capsys.readouterr()
    assert code == 0, err
    preset, overrides = printed_overrides(stdout)
    assert 'frame_skip=20' in overrides and any(
        a.startswith('randomize_damping=') for a in overrides)
    cfg = load_config(config_file(preset), overrides + SHORT)
    summary = train_inprocess(cfg, 100_000, eval_episodes=50)
    still = evaluate_policy(StandStill(7), str(out), 50, 0, frame_skip=20)
    trained, standing = summary['eval_final_distance'], still['eval_final_distance']
    assert np.isfinite(trained) and trained < 0.8 * standing, (trained, standing)
