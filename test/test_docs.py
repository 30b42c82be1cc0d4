"""
The documentation's links stay in the repository.

Every relative link of README.md, BENCHMARKS.md and docs/ names a file of this repository:
a newcomer's clone has nothing outside it.
"""
from pathlib import Path
import re

import pytest

REPO = Path(__file__).resolve().parent.parent
PAGES = [REPO / 'README.md', REPO / 'BENCHMARKS.md', *sorted((REPO / 'docs').glob('*.md'))]
# a markdown link's target, or a path in backticks that leaves its folder ("`../x/y.md`")
LINK = re.compile(r'\]\(([^)\s]+)\)|`(\.\./[^`\s]+)`')


def relative_links(text: str):
    """Return the link targets in ``text`` that are files (no URL, no in-page anchor)."""
    targets = [a or b for a, b in LINK.findall(text)]
    return [t.split('#')[0] for t in targets
            if t.split('#')[0] and not re.match(r'^[a-z]+:', t)]


def outside(page: Path, target: str) -> str:
    """Return why ``target`` (linked from ``page``) is not a file of the repository, or ''."""
    path = (page.parent / target).resolve()
    if not path.is_relative_to(REPO):
        return f'{page.name} links outside the repository: {target}'
    return '' if path.exists() else f'{page.name} links to a missing file: {target}'


@pytest.mark.parametrize('page', PAGES, ids=lambda p: p.name)
def test_relative_links_stay_in_the_repository(page):
    links = relative_links(page.read_text())
    assert [why for why in (outside(page, t) for t in links) if why] == []


def test_the_check_sees_the_readme_link_of_before():
    """The README used to send readers to the notes outside the repository."""
    before = 'The notes are `../shared/reference/likelihood_ratio_policy_gradients.md`.'
    (target,) = relative_links(before)
    assert 'outside the repository' in outside(REPO / 'README.md', target)
    assert 'docs/theory.md' in relative_links((REPO / 'README.md').read_text())


def test_the_smallest_arm_of_docs_mjcf_is_an_arm(tmp_path):
    """docs/mjcf.md's example passes the check that train makes, and steps."""
    from pg_node.sim.arm_task import ArmTask, check_arm
    xml = re.search(r'```xml\n(.*?)```', (REPO / 'docs' / 'mjcf.md').read_text(), re.S)
    (tmp_path / 'tiny.xml').write_text(xml.group(1))
    assert check_arm(tmp_path / 'tiny.xml').joint_names == ('joint0',)
    task = ArmTask(tmp_path / 'tiny.xml', num_envs=2, seed=0)
    task.reset()
    assert task.step([[0.5], [-0.5]])[0].shape == (2, 3 + 2 * 2)
