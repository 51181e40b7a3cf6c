"""Lay out the venv's editable ROS packages the way a colcon install does, for ROS's own tools.

``pip install -e`` puts a package's console scripts in ``<venv>/bin`` and installs none of its
``data_files``. ``ros2 run``, ``ros2 pkg`` and ``ros2 launch`` look elsewhere: the ament index
(``<prefix>/share/ament_index/resource_index/packages/<package>``), the package's share
directory (``package.xml``, launch files) and ``<prefix>/lib/<package>/`` for executables (where
the packages' ``setup.cfg`` installs them in a colcon build). This links each data file of
``setup.py`` into the prefix and each console script into ``lib/<package>/``: symbolic links,
so that an edit to a node, or to a launch file, is live without reinstalling.

Called by scripts/bootstrap after the editable installs (and again whenever a ``setup.py``
changes). Usage: ``python scripts/register_packages.py PREFIX PACKAGE_DIR...``
"""

from __future__ import annotations

import os
from pathlib import Path
import shutil
import sys
from typing import Any

import setuptools


def setup_arguments(package_dir: Path) -> dict[str, Any]:
    """Return the keyword arguments ``setup.py`` in ``package_dir`` passes to ``setup()``.

    colcon reads ament_python packages the same way: it runs ``setup.py`` with ``setup()``
    replaced. The file runs in its own directory, where its relative paths (and globs) start.
    """
    captured: dict[str, Any] = {}
    real_setup = setuptools.setup
    setuptools.setup = lambda **kwargs: captured.update(kwargs)
    cwd = os.getcwd()
    try:
        os.chdir(package_dir)
        code = compile((package_dir / 'setup.py').read_text(), str(package_dir / 'setup.py'),
                       'exec')
        exec(code, {'__name__': '__main__', '__file__': str(package_dir / 'setup.py')})
    finally:
        os.chdir(cwd)
        setuptools.setup = real_setup
    return captured


def register(prefix: Path, package_dir: Path) -> str:
    """Link one package's data files and executables into ``prefix``; return its name."""
    arguments = setup_arguments(package_dir)
    name = arguments['name']
    # What an earlier run linked goes first, so that a removed file does not linger.
    for stale in (prefix / 'share' / name, prefix / 'lib' / name):
        shutil.rmtree(stale, ignore_errors=True)
    for destination, sources in arguments.get('data_files', ()):
        target_dir = prefix / destination
        target_dir.mkdir(parents=True, exist_ok=True)
        for source in sources:
            _link(package_dir / source, target_dir / Path(source).name)
    executables = prefix / 'lib' / name
    scripts = arguments.get('entry_points', {}).get('console_scripts', ())
    if scripts:
        executables.mkdir(parents=True, exist_ok=True)
    for script in scripts:
        executable = script.split('=', 1)[0].strip()
        _link(prefix / 'bin' / executable, executables / executable)
    return name


def _link(source: Path, link: Path) -> None:
    if link.is_symlink() or link.exists():
        link.unlink()
    link.symlink_to(source.resolve())


def main(argv: list[str]) -> int:
    """Register every package directory given after the prefix."""
    if len(argv) < 2:
        print(__doc__.strip().splitlines()[-1], file=sys.stderr)
        return 2
    prefix = Path(argv[0]).resolve()
    names = [register(prefix, Path(directory).resolve()) for directory in argv[1:]]
    print(f'bootstrap: registered {", ".join(names)} for ros2 run and ros2 launch',
          file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
