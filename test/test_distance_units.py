"""
One unit for the fingertip's distance to its target: centimetres, in every line and table.

``train``, ``eval`` and ``robustness`` said cm while ``play`` said m, in its lines, its
summary and its GIF's captions, and a results table said m: the scans below find a distance
formatted or tabled in metres in the tools' and benchmarks' sources and in the docs.
"""
from pathlib import Path
import re

import numpy as np
from pg_node.common.paths import resolve_model
from pg_node.sim.arm_task import ArmTask
from pg_node.tools.play import Episodes

REPO = Path(__file__).resolve().parent.parent
#: the commands' sources (the nodes' logs keep ROS's SI units, REP-103: a target 0.35 m away)
SOURCES = sorted([*(REPO / 'pg_node' / 'tools').rglob('*.py'), *(REPO / 'bench').rglob('*.py')])
PAGES = sorted([REPO / 'README.md', *(REPO / 'docs').rglob('*.md')])
#: a formatted distance followed by metres: f'{dist:.4f} m', f'{dists.mean():.3f} m)'
FORMATTED_IN_METRES = re.compile(r'\{[^{}]*dist[^{}]*\}\s?m\b')
#: a column or axis of distances in metres: 'final distance (m)'
LABELLED_IN_METRES = re.compile(r'distance[^\'"\n|]*\(m\)')
#: a number in metres: 0.262 m, **0.037 m**
METRES = re.compile(r'\d(\.\d+)?\**\s?m\b(?!/)')


def test_no_source_formats_a_distance_in_metres():
    found = [f'{path.relative_to(REPO)}:{n}: {line.strip()}' for path in SOURCES
             for n, line in enumerate(path.read_text().splitlines(), 1)
             if FORMATTED_IN_METRES.search(line) or LABELLED_IN_METRES.search(line)]
    assert found == []


def test_the_scan_finds_what_play_printed_before():
    before = ("    f'distance {dist:.4f} m', flush=True)\n"
              "    print(f'final distance {dists.mean():.4f} m (median {x:.4f} m)')\n"
              "    ax.set_ylabel('final distance (m)')")
    assert [bool(FORMATTED_IN_METRES.search(ln) or LABELLED_IN_METRES.search(ln))
            for ln in before.splitlines()] == [True, True, True]
    assert not FORMATTED_IN_METRES.search("f'{torque:.2f} N m, {100 * dist:.2f} cm'")


def distance_columns(header: str):
    """Return the indices of a markdown table's columns about a distance."""
    return [i for i, cell in enumerate(header.strip().strip('|').split('|'))
            if 'distance' in cell.lower()]


def test_no_doc_gives_a_distance_in_metres():
    found = []
    for page in PAGES:
        columns = []
        for n, line in enumerate(page.read_text().splitlines(), 1):
            where = f'{page.relative_to(REPO)}:{n}'
            if not line.lstrip().startswith('|'):
                columns = []
                if 'distance' in line.lower() and METRES.search(line):
                    found.append(f'{where}: {line.strip()}')
                continue
            cells = line.strip().strip('|').split('|')
            if not columns:
                columns = distance_columns(line)
                continue
            found += [f'{where}: {cells[i].strip()}' for i in columns
                      if i < len(cells) and METRES.search(cells[i])]
    assert found == []


def test_the_doc_scan_finds_a_table_in_metres():
    assert distance_columns('| steps | mean final distance (50 ep.) | median |') == [1]
    assert METRES.search('**0.037 m**') and METRES.search('0.8 m')
    assert not METRES.search('3.7 cm') and not METRES.search('2 m/s')


def test_play_prints_distances_and_targets_in_cm():
    task = ArmTask(resolve_model('reacher2'), num_envs=1, seed=0)
    try:
        obs = task.reset()[0]
        episodes = Episodes(task.spec.obs_layout)
    finally:
        task.close()
    line = episodes.line((3, 0, -4.5, 0.0123, [(obs, 0.0)]))
    target = obs[episodes.target]
    assert line == (f'episode    3 (arm 0): target ({100 * target[0]:.1f}, '
                    f'{100 * target[1]:.1f}) cm, return   -4.500, final fingertip distance '
                    '1.23 cm')
    assert np.all(np.abs(target) < 0.25)        # metres in the observation, cm printed
