"""
Which policy update a run uses: the :class:`Updater` protocol and the registry by ``algo``.

As in Stable-Baselines3 (one class per algorithm over a shared base), each update is a class
of its own: :class:`~pg_node.rl.a2c.A2CUpdate` and :class:`~pg_node.rl.a2c.PPOUpdate` beside
their losses, :class:`~pg_node.rl.natural_gradient.NPGUpdate` and
:class:`~pg_node.rl.natural_gradient.TRPOUpdate` beside the conjugate gradient. The learner
knows an update only through this protocol, and picks its class here by name; the math
stays in its modules, the choice lives in this one.

Each class is built from the learner parameters :data:`pg_node.rl.update_settings.SETTINGS`
gives its ``algo`` (its ``settings``): that table, free of torch, is the one place that says
which update has which, and :func:`pg_node.rl.update_settings.check_algo_setting` refuses a
setting the chosen update lacks, for ``train``'s configuration before any node starts, for
the learner when it is built and for ``ros2 param set``.
"""
from typing import Dict, Optional, Protocol, Tuple, Type

from pg_node.rl.a2c import A2CUpdate, PolicyBatch, PPOUpdate
from pg_node.rl.natural_gradient import NPGUpdate, TRPOUpdate
from pg_node.rl.update_settings import check_settings
from torch import nn


class Updater(Protocol):
    """What the learner asks of a policy update."""

    #: the ``algo`` value that chooses it
    name: str
    #: the learner settings it has, each an attribute of the same name (live ones are set)
    settings: Tuple[str, ...]
    #: the learning rate the logs show
    learning_rate: float
    #: whether a batch's observations join the running statistics after a skipped step
    merge_obs_after_skip: bool
    #: steps skipped so far for a non-finite loss or gradient
    skipped: int

    @classmethod
    def from_config(cls, policy: nn.Module, cfg: Dict) -> 'Updater':
        """Build the update of ``policy`` from the learner's configuration."""

    def update(self, batch: PolicyBatch) -> Dict[str, float]:
        """Update the policy on one batch; return its metrics (``skipped_updates`` among them)."""

    def optimizer_state(self) -> Optional[Dict]:
        """Return the optimiser's state for a checkpoint, or None if there is none."""

    def load_optimizer_state(self, state: Dict) -> None:
        """Load a checkpoint's optimiser state (the configured learning rate stays)."""


#: every policy update by the name ``algo`` gives it
UPDATERS: Dict[str, Type[Updater]] = {
    cls.name: cls for cls in (A2CUpdate, PPOUpdate, NPGUpdate, TRPOUpdate)}


def make_updater(policy: nn.Module, cfg: Dict) -> Updater:
    """
    Return the update ``cfg['algo']`` names, built from ``cfg``.

    Raises :class:`~pg_node.common.param_schema.ConfigError` when ``cfg`` gives a setting
    that update does not have a value other than its default (a node started with
    ``algo:=trpo -p clip_range:=0.3``).
    """
    check_settings('', cfg)
    return UPDATERS[cfg['algo']].from_config(policy, cfg)
