"""The packages' import rules, read from the source with ``ast`` (nothing is imported).

The vision node's package imports nothing of the detector's training (``ur_rg2_detector``,
``ur_rg2_learning``, torch); the detector's package is no ROS code (no rclpy); and the
project's modules import one another without a circle, lazy imports inside functions too.
"""

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / 'ros2_ws' / 'src'
PACKAGES = sorted(path.parent.name for path in SRC.glob('*/setup.py'))


def modules(package: str) -> dict[str, Path]:
    """Return the dotted names of a package's modules and their files."""
    root = SRC / package
    return {'.'.join(path.relative_to(root).with_suffix('').parts).removesuffix('.__init__'):
            path for path in sorted((root / package).rglob('*.py'))}


def imported(path: Path, name: str) -> set[str]:
    """Return the modules a file imports, absolute, at any depth (lazy imports too)."""
    found = set()
    package = name if path.name == '__init__.py' else name.rpartition('.')[0]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ''
            if node.level:
                parts = package.split('.')
                base = '.'.join(parts[:len(parts) - node.level + 1] + ([base] if base else []))
            found.add(base)
            # `from package import module` imports the module.
            found.update(f'{base}.{alias.name}' for alias in node.names)
    return found


ALL = {name: path for package in PACKAGES for name, path in modules(package).items()}


def top_level(names: set[str]) -> set[str]:
    return {name.partition('.')[0] for name in names}


@pytest.mark.parametrize('name', sorted(modules('ur_rg2_vision')))
def test_vision_imports_nothing_of_the_training(name):
    assert not top_level(imported(ALL[name], name)) & {
        'ur_rg2_detector', 'ur_rg2_learning', 'torch'}


@pytest.mark.parametrize('name', sorted(modules('ur_rg2_detector')))
def test_the_detector_package_is_no_ros_code(name):
    assert 'rclpy' not in top_level(imported(ALL[name], name))


def test_the_detector_package_holds_its_commands():
    assert {'train_detector', 'evaluate_detector', 'detector_net', 'scenes',
            'scene_dataset'} <= {name.rpartition('.')[2] for name in modules('ur_rg2_detector')}


def test_the_project_modules_import_one_another_without_a_circle():
    graph = {name: {other for other in imported(path, name) if other in ALL and other != name}
             for name, path in ALL.items()}
    # Depth-first search; a module met again while on the path closes a circle.
    state: dict[str, int] = {}  # 1: on the path, 2: done
    path: list[str] = []
    circles = []

    def visit(name: str) -> None:
        state[name] = 1
        path.append(name)
        for other in sorted(graph[name]):
            if state.get(other) == 1:
                circles.append(path[path.index(other):] + [other])
            elif other not in state:
                visit(other)
        path.pop()
        state[name] = 2

    for name in sorted(graph):
        if name not in state:
            visit(name)
    assert not circles, '\n'.join(' -> '.join(circle) for circle in circles)
