"""Transition message layout: round trips, documentation and refusal of bad layouts."""
import numpy as np
from pg_node.ros import table_msg, transition
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
    assert offset == 2 and data[0] == 12345 and data.shape == (2 + n * width,)
    # row i is env i: its reward sits right after its observation
    assert data[2 + obs_dim] == tr.reward[0]
    if n > 1:
        assert data[2 + width + obs_dim] == tr.reward[1]
    _assert_same(unpack(dims, offset, data), tr)


def test_message_round_trip():
    tr = _example(4, 10)
    msg = transition.to_msg(tr)
    assert msg.layout.data_offset == 2
    assert [d.label for d in msg.layout.dim][:2] == ['env', 'obs']
    _assert_same(transition.from_msg(msg), tr)


def test_a_group_message_names_its_first_arm_and_the_groups():
    """Group messages carry their first arm and G after seq; G = 1 keeps the plain layout."""
    tr = _example(3, 10)
    tr.first_arm, tr.groups = 32, 2
    dims, offset, data = pack(tr)
    assert offset == 4 and data[:4].tolist() == [12345, 32, 2, 0]      # run token 0
    back = unpack(dims, offset, data)
    _assert_same(back, tr)
    assert back.groups == 2 and back.arms == slice(32, 35)
    assert transition.from_msg(transition.to_msg(tr)).first_arm == 32
    assert pack(_example(3, 10))[1] == 2 and _example(3, 10).arms == slice(0, 3)
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
    flags[offset + 11] = 0.5  # env 0's terminated
    yield 'terminated', dims, offset, flags
    ids = data.copy()
    ids[offset + 23] = 1.5  # env 0's episode_id
    yield 'episode_id', dims, offset, ids
    seq = data.copy()
    seq[0] = np.nan
    yield 'seq', dims, offset, seq
    yield 'data_offset', dims, 5, data


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


def _group_example():
    tr = _example(5, 10, seed=1)
    tr.first_arm, tr.groups = 5, 2
    return tr


@pytest.mark.parametrize('make', [lambda: _example(4, 10), lambda: _example(64, 10),
                                  _group_example])
def test_serialised_bytes_are_the_message_rclpy_reads_and_writes(make):
    """to_cdr/from_cdr (the lock-step path, no message objects) speak rclpy's CDR."""
    from rclpy.serialization import deserialize_message, serialize_message
    from std_msgs.msg import Float64MultiArray
    tr = make()
    ref = transition.to_msg(tr)
    got = deserialize_message(transition.to_cdr(tr), Float64MultiArray)
    assert [(d.label, d.size, d.stride) for d in got.layout.dim] == \
        [(d.label, d.size, d.stride) for d in ref.layout.dim]
    assert got.layout.data_offset == ref.layout.data_offset
    assert got.data.tobytes() == ref.data.tobytes()
    _assert_same(transition.from_cdr(bytes(serialize_message(ref))), tr)
    _assert_same(transition.from_cdr(transition.to_cdr(tr)), tr)   # a known layout now


def test_remembered_layout_gives_the_codecs_bytes():
    """to_cdr's remembered layouts: the bytes rosbags' codec writes, for each layout its own."""
    table_msg._known_prefixes.clear()
    a, b = _example(64, 10, seed=2), _example(64, 10, seed=3)
    b.seq = 12346
    for tr in (a, b, _group_example(), a, _example(4, 10)):
        assert transition.to_cdr(tr) == table_msg.to_cdr(*pack(tr))
    assert len(table_msg._known_prefixes) == 3
    # the same sizes under another label: its own bytes, not the remembered ones
    dims, offset, data = pack(a)
    dims[1] = ('obz',) + tuple(dims[1][1:])
    raw = table_msg.to_cdr(dims, offset, data, remember=True)
    assert raw == table_msg.to_cdr(dims, offset, data) != transition.to_cdr(a)
    assert table_msg.from_cdr(raw).layout.dim[1].label == 'obz'


def test_serialised_decoding_checks_every_message_not_only_the_first():
    """A remembered layout skips the layout checks only; values and new layouts are checked."""
    transition._known_layouts.clear()
    tr = _example(3, 10)
    _assert_same(transition.from_cdr(transition.to_cdr(tr)), tr)
    assert len(transition._known_layouts) == 1
    for field, index, value, match in (('reward', 1, np.nan, "'reward' holds non-finite"),
                                       ('obs', (0, 2), 1e300, "'obs' holds absurd")):
        bad = _example(3, 10)
        getattr(bad, field)[index] = value
        with pytest.raises(ValueError, match=match):
            transition.from_cdr(transition.to_cdr(bad))
    # the same length with another label: not the remembered layout, so checked in full
    dims, offset, data = pack(tr)
    dims[1] = ('obz',) + tuple(dims[1][1:])
    raw = table_msg.to_cdr(dims, offset, data)
    assert len(raw) == len(transition.to_cdr(tr))
    with pytest.raises(ValueError, match='field labels'):
        transition.from_cdr(raw)
    for junk in (b'', b'\x00\x01\x00\x00', transition.to_cdr(tr)[:-5], b'xyz' * 40):
        with pytest.raises(ValueError, match='not a serialised Float64MultiArray'):
            transition.from_cdr(junk)
    _assert_same(transition.from_cdr(transition.to_cdr(tr)), tr)


@pytest.mark.parametrize('seed', range(40))
def test_checking_a_table_at_once_agrees_with_checking_it_field_by_field(seed):
    """check_fields' one-pass check of a Table returns or refuses exactly as the slow one."""
    rng = np.random.default_rng(seed)
    tr = _example(int(rng.integers(1, 9)), 10, seed)
    dims, offset, data = pack(tr)
    if seed % 4:                         # three in four get a value that breaks a rule
        data = data.copy()
        at = int(rng.integers(offset, data.size))
        data[at] = rng.choice([np.nan, np.inf, -np.inf, 2.0, -1.0, 0.5, 1e7, -1e7, 2.0**60])
    widths = {name: 10 if size is None else size for name, size in transition.FIELDS}
    _, table = table_msg.unpack(dims, offset, data, offset, widths, rows_label='env')
    assert isinstance(table, table_msg.Table)
    results = []
    for fields in (table, dict(table)):   # one pass, then field by field
        try:
            results.append(table_msg.check_fields(fields, transition.BOOL_FIELDS,
                                                  transition.INT_FIELDS))
        except ValueError as exc:
            results.append(str(exc))
    fast, slow = results
    if isinstance(slow, str):
        assert fast == slow
    else:
        assert list(fast) == list(slow)
        for name in slow:
            np.testing.assert_array_equal(fast[name], slow[name])
            assert fast[name].dtype == slow[name].dtype and fast[name].shape == slow[name].shape
