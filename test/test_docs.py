"""
The documentation's links stay in the repository, and each page says what it answers.

Every relative link of README.md and docs/ (its pages, and the reports of docs/results/) names
a file of this repository: a newcomer's clone has nothing outside it. A link to a heading
(``page.md#heading``, or ``#heading`` in the page itself) names a heading that page has, as
GitHub makes anchors of them: a section that moved to another page leaves no dead link behind.
Each page of docs/ starts, after its title, with the line that says what it answers.
"""
from pathlib import Path
import re

import pytest

REPO = Path(__file__).resolve().parent.parent
PAGES = [REPO / 'README.md', *sorted((REPO / 'docs').glob('**/*.md'))]
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


#: a markdown link's target with a heading: ``(page.md#anchor)`` or ``(#anchor)``
ANCHORED = re.compile(r'\]\(([^)\s#]*)#([^)\s]+)\)')


def anchors(text: str) -> set:
    """Return the anchors GitHub gives the headings of ``text`` (fenced blocks left out)."""
    found, fenced = set(), False
    for line in text.split('\n'):
        if line.lstrip().startswith('```'):
            fenced = not fenced
        elif not fenced and re.match(r'#{1,6} ', line):
            words = re.sub(r'[^\w\- ]', '', line.lstrip('#').strip().lower())
            found.add(words.replace(' ', '-'))
    return found


def dead_anchors(page: Path) -> list:
    """Return the links of ``page`` to a heading that their page does not have."""
    dead = []
    for target, anchor in ANCHORED.findall(page.read_text()):
        if re.match(r'^[a-z]+:', target):
            continue
        path = (page.parent / target).resolve() if target else page
        if path.suffix == '.md' and path.is_file() and anchor not in anchors(path.read_text()):
            dead.append(f'{page.name} links to a missing heading: {target}#{anchor}')
    return dead


@pytest.mark.parametrize('page', PAGES, ids=lambda p: p.name)
def test_links_to_a_heading_find_it(page):
    assert dead_anchors(page) == []


def test_the_check_sees_a_heading_that_moved(tmp_path):
    (tmp_path / 'a.md').write_text('# A\n\n## The tools (no `ros2` CLI needed)\n\n```bash\n'
                                   '# not a heading\n```\n')
    assert anchors((tmp_path / 'a.md').read_text()) == {'a', 'the-tools-no-ros2-cli-needed'}
    (tmp_path / 'b.md').write_text('# B\n\n[tools](a.md#the-tools-no-ros2-cli-needed), '
                                   '[gone](a.md#results), [here](#b), [lost](#not-a-heading)\n')
    assert dead_anchors(tmp_path / 'b.md') == [
        'b.md links to a missing heading: a.md#results',
        'b.md links to a missing heading: #not-a-heading']


@pytest.mark.parametrize('page', sorted((REPO / 'docs').glob('*.md')), ids=lambda p: p.name)
def test_each_docs_page_starts_with_what_it_answers(page):
    title, blank, first = page.read_text().split('\n')[:3]
    assert title.startswith('# ') and blank == '', page.name
    assert first.startswith('This page answers: '), f'{page.name}: {first}'


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
