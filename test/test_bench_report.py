"""
``python -m bench`` writes its block of BENCHMARKS.md and leaves the rest of the page alone.

The page opens with a summary table and holds sections that sessions wrote by hand; a run
used to write the whole file and drop them. Now it replaces only the block between the
markers, and the block it replaces goes, dated, to the log page: a run deletes nothing.
"""
import json
from pathlib import Path
import re

from bench import report, suite
import pytest
from test_bench import fake_results

REPO = Path(__file__).resolve().parent.parent
RESULTS = REPO / 'docs' / 'results'
REPORT = '# pg_node benchmarks\n\nProduced by one invocation\n\n## Machine\n\n```\n## code\n```\n'
PAGE = (f'# pg_node benchmarks\n\n## Summary\n\n| what | figure |\n\n## The bench\n\n'
        f'{report.BEGIN}\n### Machine\n\nold numbers\n{report.END}\n\n### Findings\n\nby hand\n')


def test_a_page_without_markers_is_the_report_itself():
    assert report.splice('', REPORT) == (REPORT, '')
    assert report.splice('# a page\n\nno markers\n', REPORT) == (REPORT, '')


def test_the_block_is_replaced_demoted_and_the_rest_kept():
    text, old = report.splice(PAGE, REPORT)
    assert old == '### Machine\n\nold numbers'
    head, rest = text.split(report.BEGIN)
    block, tail = rest.split(report.END)
    assert head == PAGE.split(report.BEGIN)[0]
    assert tail == PAGE.split(report.END)[1]
    # the report's title goes (the page has one); its sections sit under the page's topic
    assert block == '\nProduced by one invocation\n\n### Machine\n\n```\n## code\n```\n'


def test_the_replaced_block_goes_to_the_log_once_per_run(tmp_path):
    page, log = tmp_path / 'BENCHMARKS.md', tmp_path / report.LOG
    page.write_text(PAGE)
    log.write_text('# the log\n\nWhat left the page.\n\n## 2026-01-01: an older entry\n\nx\n')
    assert report.write(page, REPORT, '2026-02-02 10:00', archived=False)
    # the run's next report (after its next section) replaces its own block: no new entry
    assert report.write(page, REPORT.replace('one', 'this'), '2026-02-02 10:00', archived=True)
    entries = re.findall(r'^## (.*)', log.read_text(), re.M)
    assert entries == ['Replaced on 2026-02-02 10:00 (UTC) by a run of `python -m bench`: '
                       'the bench block of before', '2026-01-01: an older entry']
    assert '#### Machine\n\nold numbers' in log.read_text()
    assert 'Produced by this invocation' in page.read_text()
    assert page.read_text().endswith('### Findings\n\nby hand\n')
    # the same report rendered again (`--from-json` twice) archives nothing
    before = log.read_text()
    report.write(page, REPORT.replace('one', 'this'), '2026-02-02', archived=False)
    assert log.read_text() == before


def test_from_json_renders_into_the_page_and_logs_the_block_replaced(tmp_path):
    results = dict(fake_results(), command='python -m bench --quick')
    (tmp_path / 'r.json').write_text(json.dumps(results))
    (tmp_path / 'BENCHMARKS.md').write_text(PAGE)
    assert suite.main(['--from-json', str(tmp_path / 'r.json'), '--out', str(tmp_path)]) == 0
    text = (tmp_path / 'BENCHMARKS.md').read_text()
    assert text.startswith('# pg_node benchmarks\n\n## Summary\n')
    assert text.count('# pg_node benchmarks') == 1
    assert '### Targets' in text and '### 1. Throughput ladder' in text
    assert text.endswith('### Findings\n\nby hand\n')
    assert 'old numbers' in (tmp_path / report.LOG).read_text()


def test_the_committed_page_opens_with_the_summary_and_holds_one_block():
    text = (RESULTS / 'BENCHMARKS.md').read_text()
    assert text.count(report.BEGIN) == 1 and text.count(report.END) == 1
    summary = text.split('\n## ', 2)[1]
    assert summary.startswith('Summary\n')
    assert '| what | figure | anchor | command | commit |' in summary
    assert text.index('## Summary') < text.index(report.BEGIN)
    # the block is what a run writes: its headings under the page's topic heading
    block = text.split(report.BEGIN)[1].split(report.END)[0]
    assert not re.search(r'^#{1,2} ', block, re.M)


@pytest.mark.parametrize('row', [
    r for r in (RESULTS / 'BENCHMARKS.md').read_text().split('\n## ', 2)[1].splitlines()
    if r.startswith('| ') and not r.startswith('| what ')])
def test_each_summary_row_links_its_section_and_names_a_commit(row):
    cells = [c.strip() for c in row.strip('|').split('|')]
    assert len(cells) == 5, row
    assert re.search(r'\]\(#[\w-]+\)', cells[2]), row
    assert re.search(r'\b[0-9a-f]{7}\b', cells[4]), row
