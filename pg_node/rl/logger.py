"""
Training metrics as TensorBoard event files: ``tensorboard --logdir runs``.

The learner writes one scalar per metric and update, against the environment steps learned
(SB3's x-axis), under the names Stable-Baselines3 gives the same quantities, so that runs of
both can be compared in one TensorBoard; pg_node's own metrics go under ``pg_node/``.
"""
import math
from pathlib import Path
from typing import Dict

#: pg_node metric -> (TensorBoard tag, sign): SB3's names where SB3 logs the same quantity
TAGS = {
    'episode_return': ('rollout/ep_rew_mean', 1.0),
    'episode_length': ('rollout/ep_len_mean', 1.0),
    'policy_loss': ('train/policy_loss', 1.0),
    'value_loss': ('train/value_loss', 1.0),
    'entropy': ('train/entropy_loss', -1.0),        # SB3 logs the loss: minus the entropy
    'explained_variance': ('train/explained_variance', 1.0),
    'approx_kl': ('train/approx_kl', 1.0),
    'clip_fraction': ('train/clip_fraction', 1.0),
    'learning_rate': ('train/learning_rate', 1.0),
    'steps_per_second': ('time/fps', 1.0),
}


class TensorBoardLog:
    """Writes metrics to ``<directory>`` (event files TensorBoard reads), flushed on request."""

    def __init__(self, directory):
        from torch.utils.tensorboard import SummaryWriter
        self.directory = Path(directory)
        self.writer = SummaryWriter(str(self.directory), flush_secs=10)

    def write(self, metrics: Dict[str, float], env_steps: int) -> None:
        """
        Add one point of every finite metric at ``env_steps``.

        All of them go in one event (one ``Summary`` with a value per tag, as TensorFlow's
        writers do; TensorBoard reads each value as its tag's point): ``add_scalar`` writes
        an event per metric, several times the learner's CPU per update (the figures:
        docs/results/PROFILE.md).
        """
        from tensorboard.compat.proto.summary_pb2 import Summary
        values = []
        for name, value in metrics.items():
            try:
                value = float(value)
            except (TypeError, ValueError):
                continue
            if not math.isfinite(value):
                continue
            tag, sign = TAGS.get(name, (f'pg_node/{name}', 1.0))
            values.append(Summary.Value(tag=tag, simple_value=sign * value))
        if values:
            self.writer._get_file_writer().add_summary(Summary(value=values), int(env_steps))

    def flush(self) -> None:
        """Put what was written on disk."""
        self.writer.flush()

    def close(self) -> None:
        """Flush and close the event file."""
        self.writer.close()
