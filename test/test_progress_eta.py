"""``train``'s progress shows the time left, at the speed it shows (since the first update)."""
from pg_node.tools.progress_view import ProgressView

HEADER = 'env_steps,wall_seconds,episode_return,policy_version\n'


def test_the_progress_shows_the_time_left_at_this_sessions_speed(tmp_path):
    progress = tmp_path / 'progress.csv'
    # an earlier session's row: neither its steps nor its time count in this one's speed
    progress.write_text(HEADER + '500,5.0,-20.0,1\n')
    view = ProgressView(progress, total=10_000, start={'env_steps': 500}, bar=False)
    with open(progress, 'a') as f:
        f.write('1000,100.0,-12.5,2\n')
    view.poll()
    assert view.eta(view.last) == 'n/a'         # one update: no speed yet
    with open(progress, 'a') as f:
        f.write('3000,120.0,-10.0,6\n')         # 2000 steps in 20 s: 7000 left take 70 s
    view.poll()
    assert view.eta(view.last) == '01:10'
    assert view.describe_short(view.last) == ('ETA 01:10, 100 steps/s since 1st update, '
                                              'training return -10.00, policy v6')
    assert ', ETA 01:10, ' in view.describe(view.last)
