"""The README and the docs as Markdown: well-formed, short front page, every link lands.

Pure file reading. Each page is parsed as CommonMark (markdown-it-py, with GitHub's tables), as
GitHub renders it: a fence has to close where its author meant it to, relative links resolve
from the page's directory, anchors are GitHub's heading slugs, code is no link.
"""

from collections import Counter
from functools import cache
from pathlib import Path
import re

from markdown_it import MarkdownIt
from markdown_it.token import Token
import pytest

ROOT = Path(__file__).parents[1]
README = ROOT / 'README.md'
PAGES = [README, *sorted((ROOT / 'docs').glob('*.md')), *sorted(ROOT.glob('CHANGELOG.md'))]
MAX_README_LINES = 300

_MARKDOWN = MarkdownIt('commonmark').enable('table')
_EXTERNAL = re.compile(r'^[a-z][a-z0-9+.-]*:', re.IGNORECASE)


@cache
def tokens(path: Path) -> tuple[Token, ...]:
    """Return the page's block tokens, parsed as CommonMark with tables."""
    return tuple(_MARKDOWN.parse(path.read_text()))


def fence_problems(text: str) -> list[str]:
    """Say where a fenced code block does not end where its author meant it to.

    A fence left open runs to the end of the page, or is closed by the next block's closing
    fence and turns what follows inside out. Either way a line inside the block starts with a
    fence that would close it but for the text after it (CommonMark: a closing fence has no
    info string), or the block reaches the end of the page unclosed.
    """
    lines = text.splitlines()
    problems = []
    for token in _MARKDOWN.parse(text):
        if token.type != 'fence':
            continue
        start, end = token.map
        closer = re.compile(rf'^ {{0,3}}{re.escape(token.markup[0])}{{{len(token.markup)},}}')
        for number in range(start + 1, end):
            if closer.match(lines[number]) and lines[number].strip(token.markup[0] + ' '):
                problems.append(f'line {number + 1}: {lines[number].strip()[:40]!r} does not '
                                f'close the fence of line {start + 1} (text after the fence)')
        last = lines[end - 1] if end - 1 > start else ''
        if not (closer.match(last) and not last.strip(token.markup[0] + ' ')):
            problems.append(f'line {start + 1}: the fence is never closed')
    return problems


def prose_lines(path: Path) -> list[str]:
    """Return the page's lines outside code blocks."""
    lines = path.read_text().splitlines()
    code = {number for token in tokens(path) if token.type in ('fence', 'code_block')
            for number in range(*token.map)}
    return [line for number, line in enumerate(lines) if number not in code]


def slug(heading: str) -> str:
    """GitHub's anchor for a heading's text: lower-cased, punctuation but - and _ dropped."""
    text = heading.strip().lower()
    text = re.sub(r'[^\w\- ]', '', text)
    return text.replace(' ', '-')


def _text(inline: Token) -> str:
    """Return the text an inline token shows (code spans' content, links' text)."""
    return ''.join(child.content for child in inline.children or ()
                   if child.type in ('text', 'code_inline'))


def anchors(path: Path) -> set[str]:
    """Every heading anchor of a page, repeated headings numbered as GitHub does (-1, -2)."""
    seen: Counter = Counter()
    found = set()
    page = tokens(path)
    for heading, inline in zip(page, page[1:]):
        if heading.type == 'heading_open':
            base = slug(_text(inline))
            found.add(f'{base}-{seen[base]}' if seen[base] else base)
            seen[base] += 1
    return found


def links(path: Path) -> list[str]:
    """Return the targets of the page's links and images (autolinks too), code left out."""
    return [str(child.attrs['href' if child.type == 'link_open' else 'src'])
            for token in tokens(path) if token.type == 'inline'
            for child in token.children or () if child.type in ('link_open', 'image')]


def page_id(path: Path) -> str:
    return str(path.relative_to(ROOT))


def test_readme_is_a_front_page_of_at_most_300_lines():
    count = len(README.read_text().splitlines())
    assert count <= MAX_README_LINES, f'README.md has {count} lines: move text into docs/'


def test_the_helpers_read_links_and_slugs_as_github_does(tmp_path):
    page = tmp_path / 'page.md'
    page.write_text("# ROS 2's own tools\n\n"
                    '## Labelled data set (package `ur_rg2_vision`, executable `dataset`)\n\n'
                    '## Frames and [RViz](https://example.org)\n\n## Frames and RViz\n\n'
                    'see [a](x.md#y), ![b](p.png), `[not](code.md)` and <https://example.org>\n'
                    '\n```md\n[not](fenced.md)\n```\n')
    assert anchors(page) == {'ros-2s-own-tools', 'frames-and-rviz', 'frames-and-rviz-1',
                             'labelled-data-set-package-ur_rg2_vision-executable-dataset'}
    assert links(page) == ['https://example.org', 'x.md#y', 'p.png', 'https://example.org']


def test_the_fence_check_finds_a_fence_left_open():
    assert fence_problems('```sh\nls\n```\n\n````md\n```sh\nls\n```\n````\n') == []
    # A closing fence with text after it closes nothing: the next block's closes this one.
    left_open = '```yaml\na: 1\n``` More text\n\n## Heading\n\n```sh\nls\n```\n'
    assert fence_problems(left_open) == [
        "line 3: '``` More text' does not close the fence of line 1 (text after the fence)",
        "line 7: '```sh' does not close the fence of line 1 (text after the fence)"]
    assert fence_problems('text\n\n~~~\nls\n') == ['line 3: the fence is never closed']


@pytest.mark.parametrize('page', PAGES, ids=page_id)
def test_every_fenced_block_closes(page):
    problems = fence_problems(page.read_text())
    assert not problems, f'{page_id(page)}:\n' + '\n'.join(problems)


@pytest.mark.parametrize('page', PAGES, ids=page_id)
def test_every_relative_link_and_anchor_resolves(page):
    broken = []
    for target in links(page):
        if _EXTERNAL.match(target):
            continue
        path, _, anchor = target.partition('#')
        destination = (page.parent / path).resolve() if path else page
        if not destination.exists():
            broken.append(f'{target}: no file {destination}')
        elif anchor and destination.suffix == '.md' and anchor not in anchors(destination):
            broken.append(f'{target}: no heading #{anchor} in {page_id(destination)}')
    assert not broken, f'{page_id(page)}:\n' + '\n'.join(broken)


def test_readme_links_every_docs_page():
    linked = {(ROOT / target.partition('#')[0]).resolve() for target in links(README)
              if not _EXTERNAL.match(target)}
    unlinked = [page_id(page) for page in PAGES[1:] if page.resolve() not in linked]
    assert not unlinked, f'docs pages the README does not link: {unlinked}'


def test_package_table_lists_each_package_and_executable_once():
    rows = [line for line in prose_lines(README) if re.match(r'\| `ur_rg2_\w+` \|', line)]
    cells = [tuple(cell.strip() for cell in row.strip('|').split('|')[:2]) for row in rows]
    repeated = [cell for cell, count in Counter(cells).items() if count > 1]
    assert not repeated, f'package table rows listed more than once: {repeated}'
    packages = {package.strip('`') for package, _ in cells}
    on_disk = {path.parent.name for path in (ROOT / 'ros2_ws' / 'src').glob('*/package.xml')}
    assert packages == on_disk, f'the table lists {sorted(packages)}, the workspace has ' \
                                f'{sorted(on_disk)}'


def test_license_is_there_and_is_what_the_manifests_say():
    license_text = (ROOT / 'LICENSE').read_text()
    assert 'Apache License' in license_text and 'Version 2.0' in license_text
    for manifest in (ROOT / 'ros2_ws' / 'src').glob('*/package.xml'):
        assert '<license>Apache-2.0</license>' in manifest.read_text(), manifest
