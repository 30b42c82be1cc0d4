"""
The observation's layout: which field sits where in the vector a policy sees.

Training builds the observation in the simulator (:meth:`pg_node.sim.arm_task.ArmTask.
observe`), a robot rebuilds it from joint states (:class:`pg_node.sim.observation.
ObservationBuilder`), the bag recorder turns it back into joint states and the policy card
writes it down for whoever runs the policy. :class:`ObsLayout` is the one place that says
the order, the sizes and the slices, so that none of them can drift from the others.

For an arm of ``nj`` joints and a goal of ``k`` dimensions the fields are, in order::

    cos_q (nj) | sin_q (nj) | target (k) | qdot (nj) | fingertip_minus_target (k)

``size`` is their sum, ``3 nj + 2 k``.
"""
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import List, Mapping, Sequence, Tuple

#: the observation's fields, in order
FIELDS = ('cos_q', 'sin_q', 'target', 'qdot', 'fingertip_minus_target')
#: the fields that hold one number per arm joint (the others one per goal axis)
JOINT_FIELDS = ('cos_q', 'sin_q', 'qdot')


@dataclass(frozen=True)
class ObsLayout:
    """
    The observation of an arm with joints ``joint_names`` and a ``target_dim``-D goal.

    >>> layout = ObsLayout(('shoulder', 'elbow'), 2)
    >>> layout.size
    10
    >>> layout.slices['qdot']
    slice(6, 8, None)
    >>> [(f['name'], f['size']) for f in layout.card()]      # doctest: +NORMALIZE_WHITESPACE
    [('cos_q', 2), ('sin_q', 2), ('target', 2), ('qdot', 2), ('fingertip_minus_target', 2)]
    >>> ObsLayout.from_card(layout.card()) == layout
    True
    """

    joint_names: Tuple[str, ...]
    target_dim: int
    #: field name -> its slice of the observation, in :data:`FIELDS` order
    slices: Mapping[str, slice] = field(init=False, repr=False, compare=False)
    size: int = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        """Check the sizes and lay the fields end to end."""
        names, k = tuple(str(n) for n in self.joint_names), self.target_dim
        if not names or isinstance(k, bool) or int(k) != k or not 1 <= k <= 3:
            raise ValueError(f'an observation needs at least one joint and a 1-3 D target, '
                             f'not {len(names)} joints and target_dim {k!r}')
        object.__setattr__(self, 'joint_names', names)
        object.__setattr__(self, 'target_dim', int(k))
        slices, start = {}, 0
        for name in FIELDS:
            stop = start + self.field_size(name)
            slices[name] = slice(start, stop)
            start = stop
        object.__setattr__(self, 'slices', MappingProxyType(slices))
        object.__setattr__(self, 'size', start)

    @classmethod
    def of(cls, spec) -> 'ObsLayout':
        """Return the layout of an arm spec (anything with ``joint_names`` and ``target_dim``)."""
        return cls(tuple(spec.joint_names), spec.target_dim)

    @property
    def n_joints(self) -> int:
        """Return the number of arm joints."""
        return len(self.joint_names)

    def field_size(self, name: str) -> int:
        """Return how many numbers field ``name`` holds."""
        self._check(name)
        return self.n_joints if name in JOINT_FIELDS else self.target_dim

    def card(self) -> List[dict]:
        """
        Return the layout as a policy card writes it: per field ``name``, ``size`` and ``of``.

        ``of`` names what each number is about: the joints, or the goal's axes ``x``, ``y``,
        ``z``. Cards and bags already written hold this form, so it must not change.
        """
        axes = list('xyz'[:self.target_dim])
        return [{'name': name, 'size': self.field_size(name),
                 'of': list(self.joint_names) if name in JOINT_FIELDS else axes}
                for name in FIELDS]

    @classmethod
    def from_card(cls, layout: Sequence[Mapping]) -> 'ObsLayout':
        """Return the layout a card's list describes (ValueError, one line, if it is not one)."""
        try:
            fields = {f['name']: f for f in layout}
            out = cls(tuple(fields['cos_q']['of']), fields['target']['size'])
        except (KeyError, TypeError, ValueError):
            out = None
        if out is None or out.card() != list(layout):
            names = [f.get('name') if isinstance(f, Mapping) else f for f in layout]
            raise ValueError(f'the observation layout {names} is not the one pg_node builds '
                             f'({", ".join(FIELDS)}, each with its size and what it is of)')
        return out

    def _check(self, name: str):
        """Raise KeyError, naming the fields, if ``name`` is not one."""
        if name not in FIELDS:
            raise KeyError(f'no observation field {name!r} (the fields: {", ".join(FIELDS)})')
