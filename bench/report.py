"""
Where ``python -m bench`` writes its report: a whole new file, or its block of a page.

docs/results/BENCHMARKS.md is a page that sessions write too: it opens with a summary table
and holds sections measured by other scripts. The bench's own tables live there between
:data:`BEGIN` and :data:`END`, and a run replaces only that block, its headings one level
down (they sit under the page's topic heading), so the page's hand-written parts stay. The
block it replaces is history: it goes to the top of the log page beside the report
(:data:`LOG`), dated, so that a run deletes nothing. A report without the markers (a new file,
``--out`` elsewhere, PROFILE.md) is written whole, as the bench renders it.
"""
from pathlib import Path
import re
from typing import Tuple

#: the line before the bench's block in a page
BEGIN = '<!-- python -m bench writes from here to its end marker -->'
#: the line after it
END = '<!-- python -m bench writes up to here -->'
#: the log page, beside the report, that receives the block a run replaced
LOG = 'LOG.md'


def demote(text: str) -> str:
    """Return ``text`` with each heading one level down (``##`` to ``###``), code left as is."""
    out, fenced = [], False
    for line in text.split('\n'):
        if line.lstrip().startswith('```'):
            fenced = not fenced
        elif not fenced and re.match(r'#{1,5} ', line):
            line = '#' + line
        out.append(line)
    return '\n'.join(out)


def block_of(report: str) -> str:
    """Return the rendered report as the page's block: its title dropped, headings demoted."""
    body = report.split('\n', 1)[1] if report.startswith('# ') else report
    return demote(body.strip('\n'))


def splice(page: str, report: str) -> Tuple[str, str]:
    """
    Return the page with the bench's block replaced by ``report``, and the block replaced.

    A page without both markers (or none at all) is the report itself: ``(report, '')``.
    """
    if BEGIN not in page or END not in page.split(BEGIN, 1)[1]:
        return report, ''
    head, rest = page.split(BEGIN, 1)
    old, tail = rest.split(END, 1)
    return f'{head}{BEGIN}\n{block_of(report)}\n{END}{tail}', old.strip('\n')


def archive(log: Path, block: str, date: str) -> None:
    """Put ``block``, the bench's block a run replaced, at the top of the log's entries."""
    entry = (f'## Replaced on {date} (UTC) by a run of `python -m bench`: the bench block of '
             f'before\n\n{demote(block)}\n\n')
    text = log.read_text() if log.exists() else '# pg_node benchmarks: the log\n\n'
    at = text.find('\n## ')
    text = text + entry if at < 0 else text[:at + 1] + entry + text[at + 1:]
    log.write_text(text)


def write(path: Path, report: str, date: str, archived: bool) -> bool:
    """
    Write ``report`` to ``path``: into its block if it has one, else whole.

    The block replaced goes to the log unless ``archived`` (this run archived already: a run
    writes its report after every section) or it is the report's block already. Returns
    whether the block of before is dealt with, the ``archived`` of the run's next write.
    """
    page = path.read_text() if path.exists() else ''
    text, old = splice(page, report)
    if old and not archived and old != block_of(report):
        archive(path.parent / LOG, old, date)
    path.write_text(text)
    return archived or bool(old)
