"""Transition message layout: round trips, documentation and refusal of bad layouts."""
import numpy as np
from pg_node.ros import transition
from pg_node.ros.transition import pack, Transition, unpack
import pytest


def _example(n=3, obs_dim=10, seed=0):
    rng = np.random.default_rng(seed)
    return Transition(
        seq=12345, obs=rng.normal(size=(n, obs_dim)), reward=rng.normal(size=n),
        terminated=rng.random(n) < 0.5, truncated=rng.random(n) < 0.5,
        final_obs=rng.normal(size=(n, obs_dim)), episode_id=rng.integers(0, 2**40, n),
        episode_step=rng.integers(0, 50, n))


def _assert_same(a, b):
    assert (a.seq, a.first_arm, a.groups) == (b.seq, b.first_arm, b.groups)
    for name, _ in transition.FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        np.testing.assert_array_equal(x, y, name)
        assert np.asarray(x).dtype == np.asarray(y).dtype, name


@pytest.mark.parametrize('n,obs_dim', [(1, 10), (3, 10), (64, 21)])
def test_pack_unpack_round_trip(n, obs_dim):
    tr = _example(n, obs_dim)
    dims, offset, data = pack(tr)
    width = 2 * obs_dim + 5
    assert dims[0] == ('env', n, n * width)
    assert [d[0] for d in dims[1:]] == ['obs', 'reward', 'terminated', 'truncated',
                                        'final_obs', 'episode_id', 'episode_step']
    assert offset == 1 and data[0] == 12345 and data.shape == (1 + n * width,)
    # row i is env i: its reward sits right after its observation
    assert data[1 + obs_dim] == tr.reward[0]
    if n > 1:
        assert data[1 + width + obs_dim] == tr.reward[1]
    _assert_same(unpack(dims, offset, data), tr)


def test_message_round_trip():
    tr = _example(4, 10)
    msg = transition.to_msg(tr)
    assert msg.layout.data_offset == 1
    assert [d.label for d in msg.layout.dim][:2] == ['env', 'obs']
    _assert_same(transition.from_msg(msg), tr)


def test_a_group_message_names_its_first_arm_and_the_groups():
    """Group messages carry their first arm and G after seq; G = 1 keeps the plain layout."""
    tr = _example(3, 10)
    tr.first_arm, tr.groups = 32, 2
    dims, offset, data = pack(tr)
    assert offset == 3 and data[:3].tolist() == [12345, 32, 2]
    back = unpack(dims, offset, data)
    _assert_same(back, tr)
    assert back.groups == 2 and back.arms == slice(32, 35)
    assert transition.from_msg(transition.to_msg(tr)).first_arm == 32
    assert pack(_example(3, 10))[1] == 1 and _example(3, 10).arms == slice(0, 3)
    for i, bad, match in ((1, -1.0, '< 0'), (1, 0.5, 'whole'), (2, 0.0, 'groups 0 < 1')):
        data_bad = data.copy()
        data_bad[i] = bad
        with pytest.raises(ValueError, match=match):
            unpack(dims, offset, data_bad)


def test_docstring_table_lists_every_field():
    for name, _ in transition.FIELDS:
        assert f'``{name}``' in transition.__doc__


def _bad_layouts():
    dims, offset, data = pack(_example(2, 10))
    swapped = list(dims)
    swapped[2], swapped[3] = swapped[3], swapped[2]
    yield 'labels', swapped, offset, data
    yield 'labels', [('arm',) + dims[0][1:]] + dims[1:], offset, data
    yield 'labels', dims[:-1], offset, data
    yield 'size', dims[:2] + [('reward', 2, 2)] + dims[3:], offset, data
    yield 'stride', [('env', 2, 99)] + dims[1:], offset, data
    yield 'values', dims, offset, data[:-1]
    yield 'data_offset', dims, 0, data
    flags = data.copy()
    flags[1 + 11] = 0.5  # env 0's terminated
    yield 'terminated', dims, offset, flags
    ids = data.copy()
    ids[1 + 23] = 1.5  # env 0's episode_id
    yield 'episode_id', dims, offset, ids
    seq = data.copy()
    seq[0] = np.nan
    yield 'seq', dims, offset, seq
    yield 'data_offset', dims, 2, data


@pytest.mark.parametrize('match,dims,offset,data', list(_bad_layouts()))
def test_mismatched_layout_is_a_clear_value_error(match, dims, offset, data):
    with pytest.raises(ValueError, match=match):
        unpack(dims, offset, data)


def test_pack_refuses_wrong_field_sizes():
    tr = _example(2, 10)
    tr.final_obs = tr.final_obs[:, :9]
    with pytest.raises(ValueError, match='final_obs'):
        pack(tr)
    tr = _example(2, 10)
    tr.obs = tr.obs[0]
    with pytest.raises(ValueError, match='obs'):
        pack(tr)
