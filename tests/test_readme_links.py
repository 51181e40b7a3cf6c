"""The README as a front page: short, its links and the docs pages' links all land somewhere.

Pure file reading: links are checked the way GitHub renders them (relative paths from the
page's directory, anchors as GitHub's heading slugs), outside code blocks and code spans.
"""

from collections import Counter
from pathlib import Path
import re

import pytest

ROOT = Path(__file__).parents[1]
README = ROOT / 'README.md'
PAGES = [README, *sorted((ROOT / 'docs').glob('*.md'))]
MAX_README_LINES = 300

_FENCE = re.compile(r'^(```|~~~)')
_CODE_SPAN = re.compile(r'(`+)(?:(?!\1).)+?\1')
_LINK = re.compile(r'!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(([^()\s]+)(?:\s+"[^"]*")?\)')
_HEADING = re.compile(r'^(#{1,6})\s+(.*?)\s*#*\s*$')
_EXTERNAL = re.compile(r'^[a-z][a-z0-9+.-]*:', re.IGNORECASE)


def prose_lines(path: Path) -> list[str]:
    """Return the page's lines outside fenced code blocks."""
    lines, fenced = [], False
    for line in path.read_text().splitlines():
        if _FENCE.match(line.lstrip()):
            fenced = not fenced
            continue
        if not fenced:
            lines.append(line)
    return lines


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: its text lower-cased, punctuation but - and _ dropped."""
    text = re.sub(r'!?\[([^\]]*)\]\([^)]*\)', r'\1', heading)  # a link shows its text
    text = text.replace('`', '').strip().lower()
    text = re.sub(r'[^\w\- ]', '', text)
    return text.replace(' ', '-')


def anchors(path: Path) -> set[str]:
    """Every heading anchor of a page, repeated headings numbered as GitHub does (-1, -2)."""
    seen: Counter = Counter()
    found = set()
    for line in prose_lines(path):
        match = _HEADING.match(line)
        if match:
            base = slug(match.group(2))
            found.add(f'{base}-{seen[base]}' if seen[base] else base)
            seen[base] += 1
    return found


def links(path: Path) -> list[str]:
    """Return the targets of the page's Markdown links and images, code left out."""
    targets = []
    for line in prose_lines(path):
        targets += _LINK.findall(_CODE_SPAN.sub('', line))
    return targets


def page_id(path: Path) -> str:
    return str(path.relative_to(ROOT))


def test_readme_is_a_front_page_of_at_most_300_lines():
    count = len(README.read_text().splitlines())
    assert count <= MAX_README_LINES, f'README.md has {count} lines: move text into docs/'


def test_the_helpers_read_links_and_slugs_as_github_does():
    assert slug("ROS 2's own tools") == 'ros-2s-own-tools'
    assert slug('Labelled data set (package `ur_rg2_vision`, executable `dataset`)') == (
        'labelled-data-set-package-ur_rg2_vision-executable-dataset')
    assert slug('Learning: Gymnasium environments, a DDPG baseline and the policy node') == (
        'learning-gymnasium-environments-a-ddpg-baseline-and-the-policy-node')
    assert slug('Frames and RViz') == 'frames-and-rviz'
    line = 'see [a](x.md#y), ![b](p.png), `[not](code.md)` and <https://example.org>'
    assert _LINK.findall(_CODE_SPAN.sub('', line)) == ['x.md#y', 'p.png']


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
