"""
The training graph as data: which processes run, the nodes each holds, where and with what.

``python -m pg_node train`` (:mod:`pg_node.tools.train`) and ``launch/train.launch.py`` both
start what a plan lists, each in its own words (commands and parameter files; launch_ros
``Node`` actions), so the two cannot start different graphs. A plan is a list of
:class:`Process`: the critic's and the learner's first, in the run's namespace ``/<run_id>``,
then each simulator/actor :class:`Pair`'s. The run's only pair lives in the run's namespace;
pair ``i`` of several in ``/<run_id>/arm<i>``, where actor ``i`` gets ``actor_id`` i and
simulator ``i`` seeds its arms from ``seed + i * num_envs`` (:func:`sim_seed`), so that no
two arms of the run draw the same episodes. Composed, a pair is one process
(``sim_and_actor``) and the critic and the learner another (``critic_and_learner``);
otherwise each node is a process of its own.

The standard library only (and :mod:`pg_node.common.run`, which is too): ``ros2 launch`` may
run another Python than the one pg_node's dependencies were installed into, and the launch
file imports this module.
"""
from typing import Dict, List, NamedTuple, Optional, Sequence

from pg_node.common.run import pair_namespace, placed_namespace, run_namespace

#: what one host runs of a run: all of it, the critic and the learner, or pairs
PARTS = ('all', 'learner', 'workers')
#: a simulator/actor pair's processes, (executable, its nodes), the simulator's first:
#: composed (True) or a process per node
PAIR_PROCESSES = {True: (('sim_and_actor', ('sim_node', 'actor_node')),),
                  False: (('sim_node', ('sim_node',)), ('actor_node', ('actor_node',)))}
#: the critic's and the learner's processes, the learner's last: composed or not
TRAINING_PROCESSES = {True: (('critic_and_learner', ('critic_node', 'learner_node')),),
                      False: (('critic_node', ('critic_node',)),
                              ('learner_node', ('learner_node',)))}
#: the node whose exit ends the training
LEARNER = 'learner_node'
#: the node a pair's seed is for
SIMULATOR = 'sim_node'


def module_of(executable: str) -> str:
    """
    Return the module a package executable runs (``python -m`` starts it so).

    >>> module_of('sim_and_actor')
    'pg_node.ros.sim_and_actor'
    """
    return f'pg_node.ros.{executable}'


def sim_seed(seed: int, num_envs: int, actor_id: int) -> int:
    """
    Return the seed of simulator ``actor_id``: its arms follow the previous ones' seeds.

    >>> [sim_seed(5, 16, i) for i in range(3)]
    [5, 21, 37]
    """
    return seed + actor_id * num_envs


class Pair(NamedTuple):
    """One simulator/actor pair: its actor id, namespace and simulator seed."""

    actor_id: int
    namespace: str
    #: the simulator's seed; None: the parameter file's
    seed: Optional[int]
    #: what its processes' names end with: '' for the run's only pair, else ``_<actor_id>``
    tag: str = ''

    def values(self) -> Dict[str, dict]:
        """Return ``{node: values}``: what sets this pair apart from the run's others."""
        sim = {} if self.seed is None else {'seed': self.seed}
        return {SIMULATOR: sim, 'actor_node': {'actor_id': self.actor_id}}


class Process(NamedTuple):
    """One process of the graph and the values each of its nodes gets beyond the file."""

    #: its name in the plan (train's log file and restarts): the executable and a pair's tag
    name: str
    #: the package's executable (``lib/pg_node/<executable>``)
    executable: str
    namespace: str
    #: ``{node name: values}``, the nodes in the order the process holds them
    values: Dict[str, dict]
    #: the pair it runs (None: the critic's and the learner's)
    pair: Optional[Pair] = None

    @property
    def module(self) -> str:
        """Return the module that runs it (:func:`module_of`)."""
        return module_of(self.executable)


def run_pairs(run_id: str, seed: int, num_envs: int, num_actors: Optional[int],
              actors: Optional[Sequence[int]] = None) -> List[Pair]:
    """
    Return the pairs of a run of ``num_actors`` (only those of ``actors``, when given).

    ``num_actors`` None: ``actors`` are some of several pairs, whose count is not known here
    (the launch file's ``part:=workers``). Raises ValueError for an actor id the run does
    not have.

    >>> run_pairs('exp1', 5, 16, 1)
    [Pair(actor_id=0, namespace='/exp1', seed=5, tag='')]
    >>> [(p.namespace, p.seed, p.tag) for p in run_pairs('exp1', 5, 16, 3, [2])]
    [('/exp1/arm2', 37, '_2')]
    """
    if num_actors == 1:
        return [Pair(0, run_namespace(run_id), seed)]
    ids = list(range(num_actors) if actors is None else actors)
    wrong = [i for i in ids if i < 0 or (num_actors is not None and i >= num_actors)]
    if wrong:
        raise ValueError(f'actor ids {",".join(map(str, wrong))} are not of a run of '
                         f'num_actors {num_actors}')
    return [Pair(i, pair_namespace(run_id, i, num_actors), sim_seed(seed, num_envs, i), f'_{i}')
            for i in ids]


def placed_pair(run_id: str, namespace: str, actor_id: int, seed: Optional[int]) -> Pair:
    """
    Return a pair placed by hand: in ``namespace`` (under the run's unless absolute).

    What ``ros2 launch pg_node train.launch.py namespace:=... actor_id:=...`` starts; its
    simulator takes the run's ``seed`` as it is.
    """
    return Pair(actor_id, placed_namespace(run_id, namespace), seed)


def graph_plan(run_id: str, run_dir: str, pairs: Sequence[Pair], compose: bool = True,
               learner: bool = True) -> List[Process]:
    """
    Return the processes of the critic and the learner (if ``learner``) and of ``pairs``.

    Every node gets the run's id; the critic and the learner its directory; a pair's nodes
    their :meth:`Pair.values`.
    """
    run = {'run_id': run_id}
    plan = []
    if learner:
        plan += [Process(executable, executable, run_namespace(run_id),
                         {node: {**run, 'run_dir': run_dir} for node in nodes})
                 for executable, nodes in TRAINING_PROCESSES[compose]]
    for pair in pairs:
        own = pair.values()
        plan += [Process(executable + pair.tag, executable, pair.namespace,
                         {node: {**run, **own[node]} for node in nodes}, pair)
                 for executable, nodes in PAIR_PROCESSES[compose]]
    return plan


def part_plan(run_id: str, run_dir: str, seed: Optional[int], num_envs: Optional[int],
              num_actors: Optional[int],
              compose: bool = True, part: str = 'all',
              actors: Optional[Sequence[int]] = None) -> List[Process]:
    """
    Return what one host starts of a run: all of it, or its ``part`` (:data:`PARTS`).

    ``learner``: the critic and the learner; ``workers``: the pairs of ``actors`` (default:
    every pair). The seed and counts are those of :func:`run_pairs` (unused by ``learner``).
    """
    if part not in PARTS:
        raise ValueError(f'part {part!r}: one of {", ".join(PARTS)}')
    pairs = [] if part == 'learner' else run_pairs(run_id, seed, num_envs, num_actors, actors)
    return graph_plan(run_id, run_dir, pairs, compose, learner=part != 'workers')


def learner_process(compose: bool) -> str:
    """Return the name of the process the learner runs in."""
    return next(executable for executable, nodes in TRAINING_PROCESSES[compose]
                if LEARNER in nodes)
