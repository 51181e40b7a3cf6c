"""The size rules of the packages' code, read with ``ast`` (nothing is imported).

No module of ros2_ws/src over MAX_FILE_LINES lines, no node module (``*_node.py``) over
MAX_NODE_LINES (a node is wiring), no function or method over MAX_FUNCTION_LINES.
"""

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / 'ros2_ws' / 'src'
FILES = sorted(path for path in SRC.glob('*/*/**/*.py') if '__pycache__' not in path.parts)
MAX_FILE_LINES = 400
MAX_NODE_LINES = 300
MAX_FUNCTION_LINES = 80


def name(path: Path) -> str:
    return str(path.relative_to(SRC))


def test_there_are_files_to_check():
    assert len(FILES) > 50


@pytest.mark.parametrize('path', FILES, ids=name)
def test_module_and_function_lengths(path):
    text = path.read_text()
    limit = MAX_NODE_LINES if path.name.endswith('_node.py') else MAX_FILE_LINES
    assert len(text.splitlines()) <= limit
    long = [f'{node.name}: {node.end_lineno - node.lineno + 1} lines'
            for node in ast.walk(ast.parse(text, str(path)))
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
            and node.end_lineno - node.lineno + 1 > MAX_FUNCTION_LINES]
    assert not long, f'over {MAX_FUNCTION_LINES} lines: {long}'
