"""docker/Dockerfile without a Docker engine: lint, build context, and what pip would install.

No image is built here. What is checked: hadolint; that the build context holds exactly what
the Dockerfile copies; that the image's pins (requirements-ros.txt) follow requirements.txt
except where ROS Jazzy's NumPy 1.26 forces older versions; and, with pip's resolver against the
package index, that the image's install set for CPython 3.12 on manylinux x86_64 keeps NumPy 1.
"""

import json
from pathlib import Path
import re
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET

from packaging.markers import default_environment
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version
import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCKERFILE = ROOT / 'docker/Dockerfile'
DOCKERIGNORE = ROOT / 'docker/Dockerfile.dockerignore'
ROS_PINS = ROOT / 'requirements-ros.txt'
# The only pins of requirements-ros.txt allowed to differ from requirements.txt: requirements.txt's
# versions need NumPy 2.
NUMPY_1_BUILDS = {'numpy', 'opencv-python-headless'}
# ROS packages the base image (ros-base) has for sure: rclpy and the messages of rcl_interfaces
# and common_interfaces. Any other ROS dependency of a node must be on the Dockerfile's apt line.
ROS_BASE = {
    'rclpy', 'action_msgs', 'builtin_interfaces', 'lifecycle_msgs', 'rcl_interfaces',
    'rosgraph_msgs', 'service_msgs', 'statistics_msgs', 'type_description_interfaces',
    'actionlib_msgs', 'diagnostic_msgs', 'geometry_msgs', 'nav_msgs', 'sensor_msgs',
    'shape_msgs', 'std_msgs', 'std_srvs', 'stereo_msgs', 'trajectory_msgs', 'visualization_msgs',
}
# Ubuntu 24.04 has glibc 2.39: every manylinux wheel for x86_64 up to that runs in the image.
PLATFORMS = ['manylinux1_x86_64', 'manylinux2010_x86_64', 'manylinux2014_x86_64',
             *(f'manylinux_2_{minor}_x86_64' for minor in range(5, 40))]
# The marker environment of Ubuntu 24.04's Python 3.12 (pip evaluates markers such as
# `python_version >= "3.12"` for the Python it runs on, whatever --python-version says).
UBUNTU_PYTHON = {**default_environment(), 'python_version': '3.12',
                 'python_full_version': '3.12.3', 'implementation_version': '3.12.3',
                 'platform_machine': 'x86_64', 'sys_platform': 'linux', 'extra': ''}
# How pip reports an index it cannot reach (after its retries), as opposed to a failed resolution.
UNREACHABLE = re.compile(r'.*(NewConnectionError|ConnectTimeout|ReadTimeout|ProxyError'
                         r'|Max retries exceeded|Temporary failure in name resolution'
                         r'|Network is unreachable|Could not fetch URL).*')


def pins(path: Path) -> dict[str, str]:
    """Return ``{name: version}`` of the ``name==version`` lines of a requirements file."""
    found = {}
    for line in path.read_text().splitlines():
        match = re.fullmatch(r'([A-Za-z0-9_.-]+)==(\S+)', line.split('#')[0].strip())
        if match:
            found[canonicalize_name(match[1])] = match[2]
    return found


def pip_install_options(text: str) -> set[str]:
    """Return the ``--`` options of the first ``pip install`` command in ``text``."""
    command = re.search(r'pip install ((?:[^\n\\]|\\\n)+)', text)[1].replace('\\\n', ' ')
    return {word for word in command.split() if word.startswith('--')}


def source_builds() -> set[str]:
    """Return the packages the image compiles (``--no-binary``); everything else is a wheel."""
    return {canonicalize_name(name)
            for name in re.search(r'--no-binary=(\S+)', DOCKERFILE.read_text())[1].split(',')}


def resolve(tmp_path: Path, *requirements: str, python: str = '3.12',
            no_deps: bool = False) -> subprocess.CompletedProcess:
    """Run pip's resolver for ``requirements`` on ``python`` on manylinux x86_64, wheels only.

    Starts from an empty environment (``--ignore-installed``). The report's ``install`` list is
    in ``tmp_path / 'report.json'``. Skips the test, with pip's own words, only when the index
    cannot be reached.
    """
    report = tmp_path / 'report.json'
    report.unlink(missing_ok=True)
    command = [sys.executable, '-m', 'pip', 'install', '--dry-run', '--quiet',
               '--ignore-installed', '--report', str(report), '--only-binary=:all:',
               '--python-version', python, '--implementation', 'cp',
               '--abi', 'cp' + python.replace('.', ''), *(f'--platform={p}' for p in PLATFORMS),
               '--timeout', '10', '--retries', '1', *(['--no-deps'] if no_deps else []),
               *requirements]
    try:
        run = subprocess.run(command, capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired:
        pytest.skip('package index unreachable, the resolver did not run: no answer in 120 s')
    if run.returncode != 0 and (unreachable := UNREACHABLE.search(run.stdout + run.stderr)):
        pytest.skip(f'package index unreachable, the resolver did not run: {unreachable[0]}')
    return run


def installs(tmp_path: Path) -> dict[str, dict]:
    """Return the ``install`` entries of the last :func:`resolve` report, by package name."""
    report = json.loads((tmp_path / 'report.json').read_text())
    return {canonicalize_name(item['metadata']['name']): item for item in report['install']}


def unmet_requirements(resolved: dict[str, dict]) -> list[str]:
    """Return the requirements, under Python 3.12's markers, that ``resolved`` does not meet."""
    unmet = []
    for name, item in resolved.items():
        for requirement in map(Requirement, item['metadata'].get('requires_dist') or []):
            if requirement.marker and not requirement.marker.evaluate(UBUNTU_PYTHON):
                continue
            have = resolved.get(canonicalize_name(requirement.name))
            if have is None or not requirement.specifier.contains(
                    have['metadata']['version'], prereleases=True):
                unmet.append(f'{name} requires {requirement}')
    return unmet


def in_build_context(path: str) -> bool:
    """Whether ``path`` (relative to the repository root) is sent to the image build.

    Docker's rule: the last .dockerignore pattern that matches the path or one of its parent
    directories decides, ``!`` including; ``*`` and ``?`` stay within one path segment, ``**``
    spans any number of them.
    """
    included = True
    parts = path.split('/')
    prefixes = ['/'.join(parts[:end]) for end in range(1, len(parts) + 1)]
    for line in DOCKERIGNORE.read_text().splitlines():
        line = line.strip()
        if not line or line.startswith('#'):
            continue
        pattern = line.removeprefix('!').strip('/')
        regex = ''.join(
            {'**/': '(?:.*/)?', '**': '.*', '*': '[^/]*', '?': '[^/]'}.get(token)
            or re.escape(token) for token in re.findall(r'\*\*/|\*\*|\*|\?|[^*?]+', pattern))
        if any(re.fullmatch(regex, prefix) for prefix in prefixes):
            included = line.startswith('!')
    return included


def test_hadolint_passes():
    hadolint = shutil.which('hadolint', path=str(Path(sys.executable).parent))
    assert hadolint, 'hadolint is missing: run scripts/bootstrap requirements-dev.txt'
    lint = subprocess.run([hadolint, '--no-color', str(DOCKERFILE)], capture_output=True,
                          text=True, timeout=60)
    assert lint.returncode == 0, lint.stdout + lint.stderr


def test_base_image_is_the_official_ros_image_of_the_pinned_distribution():
    distros = {name.split('-')[1] for name in pins(ROOT / 'requirements.txt')
               if name.startswith('ros-')}
    assert distros == {'jazzy'}
    base = re.search(r'^FROM (\S+)', DOCKERFILE.read_text(), re.MULTILINE)[1]
    assert base in ('ros:jazzy', 'ros:jazzy-ros-base', 'ros:jazzy-ros-core')
    # Every path into /opt/ros names the same distribution.
    for path in ('docker/Dockerfile', 'docker/ros_entrypoint.sh'):
        assert set(re.findall(r'/opt/ros/(\w+)', (ROOT / path).read_text())) == {'jazzy'}


def test_image_installs_ros_messages_from_apt():
    apt = re.search(r'apt-get install ((?:[^\n\\]|\\\n)+)', DOCKERFILE.read_text())[1].split()
    # The distribution's tf2_msgs and control_msgs, never the copies the pip path builds.
    assert {'ros-jazzy-tf2-msgs', 'ros-jazzy-control-msgs'} <= set(apt)
    # Every ROS package a node declares is in the base image, installed explicitly, or one of
    # the workspace's own packages (colcon builds them).
    manifests = list((ROOT / 'ros2_ws/src').glob('*/package.xml'))
    workspace = {manifest.parent.name for manifest in manifests}
    for manifest in manifests:
        for depend in ET.parse(manifest).iter():
            key = (depend.text or '').strip()
            if (depend.tag in ('depend', 'exec_depend') and not key.startswith('python')
                    and key not in workspace):
                assert key in ROS_BASE or f'ros-jazzy-{key.replace("_", "-")}' in apt, (
                    f'{manifest.parent.name} needs {key}: add its apt package to the Dockerfile')


def test_image_and_docs_install_requirements_ros_the_same_way():
    dockerfile = DOCKERFILE.read_text()
    assert 'COPY requirements-ros.txt /tmp/requirements-ros.txt' in dockerfile
    assert re.search(r'pip install [^&]*-r /tmp/requirements-ros\.txt', dockerfile)
    options = pip_install_options(dockerfile)
    # Wheels only but for the source builds, and those against the environment's NumPy.
    assert {'--only-binary=:all:', '--no-build-isolation'} <= options
    assert source_builds() == {'pybullet'}
    # No version written into the Dockerfile itself that could drift from the pins.
    assert not re.findall(r'\b[A-Za-z][\w.-]*==\d', dockerfile)
    # The docs' colcon recipe over a ROS install: the same file, the same options.
    page = (ROOT / 'docs' / 'ros-install.md').read_text()
    recipe = page[page.index('# The ROS way'):page.index('## Docker')]
    assert re.search(r'pip install [^\n]*-r requirements-ros\.txt', recipe)
    assert pip_install_options(recipe) == options - {'--no-cache-dir'}
    assert 'requirements.txt' not in recipe.split('```')[1], 'the recipe would get NumPy 2'


def test_ros_pins_are_requirements_txt_with_numpy_1():
    pip_path, ros_path = pins(ROOT / 'requirements.txt'), pins(ROS_PINS)
    # Everything but what the ROS install itself provides (ROS from apt, with its message
    # packages, so nothing of the pip path's message build: catkin-pkg; ros2cli and launch with
    # what they import; Ubuntu's setuptools, which colcon builds with), and no package twice.
    provided = {'setuptools', 'catkin-pkg', 'osrf-pycommon', 'psutil', 'pyyaml', 'packaging'}
    assert set(ros_path) == {name for name in pip_path if not name.startswith('ros-jazzy-')
                             and name not in provided}
    assert len(ros_path) == len([line for line in ROS_PINS.read_text().splitlines()
                                 if line.strip() and not line.startswith('#')])
    differ = {name for name in ros_path if ros_path[name] != pip_path[name]}
    assert differ <= NUMPY_1_BUILDS, f'{differ - NUMPY_1_BUILDS}: not the requirements.txt version'
    # Ubuntu 24.04's python3-numpy, which ROS Jazzy's apt packages are built against.
    assert Version(ros_path['numpy']).release[:2] == (1, 26)


def test_resolver_keeps_numpy_1_in_the_image(tmp_path):
    """The image's wheels, resolved by pip for CPython 3.12 on manylinux x86_64 (glibc 2.39)."""
    ros_path = pins(ROS_PINS)
    wheels = [f'{name}=={version}' for name, version in ros_path.items()
              if name not in source_builds()]
    run = resolve(tmp_path, *wheels)
    assert run.returncode == 0, f'no consistent set of cp312 wheels:\n{run.stderr}'
    resolved = installs(tmp_path)
    print('image install set:', ', '.join(
        f"{name}=={item['metadata']['version']}" for name, item in sorted(resolved.items())))
    numpy = resolved['numpy']['metadata']['version']
    assert Version(numpy) < Version('2'), f'NumPy {numpy} would shadow the NumPy 1.26 of ROS'
    assert numpy == ros_path['numpy']
    # The set pip chose also holds together under Python 3.12's markers (pip used its own).
    assert not unmet_requirements(resolved)
    for name, item in resolved.items():
        assert item['download_info']['url'].endswith('.whl'), name
        if name in ros_path:
            assert item['metadata']['version'] == ros_path[name], name


def test_source_builds_have_no_cp312_wheel_and_do_not_require_numpy_2(tmp_path):
    ros_path = pins(ROS_PINS)
    for name in source_builds():
        pin = f'{name}=={ros_path[name]}'
        run = resolve(tmp_path, pin, no_deps=True)
        # Compiled in the image only because there is no wheel: if one appears, use it.
        assert run.returncode != 0 and 'No matching distribution' in run.stderr, (
            f'{pin} has a cp312 wheel now: drop it from --no-binary in the Dockerfile and docs')
        # The sdist's requirements are those of the same release's wheels (setup.py declares
        # them for every Python); read them from the cp311 wheel's metadata.
        run = resolve(tmp_path, pin, python='3.11', no_deps=True)
        assert run.returncode == 0, run.stderr
        requires = installs(tmp_path)[name]['metadata'].get('requires_dist') or []
        for requirement in map(Requirement, requires):
            if canonicalize_name(requirement.name) == 'numpy':
                assert requirement.specifier.contains(ros_path['numpy']), requirement


def test_build_context_holds_exactly_what_the_dockerfile_copies():
    sources = re.findall(r'^COPY (\S+) ', DOCKERFILE.read_text(), re.MULTILINE)
    for source in sources:
        assert (ROOT / source).exists(), f'COPY {source}: no such file in the repository'
    # The files a build would see: tracked, and new ones not yet committed (not .gitignored).
    tracked = subprocess.run(['git', 'ls-files', '--cached', '--others', '--exclude-standard'],
                             cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    sent = {path for path in tracked if in_build_context(path)}
    copied = {path for path in tracked
              if any(path == source or path.startswith(source + '/') for source in sources)}
    assert sent == copied
    # Every package of the workspace goes into the image, where colcon builds them all.
    for manifest in (ROOT / 'ros2_ws/src').glob('*/package.xml'):
        assert str(manifest.relative_to(ROOT)) in copied, manifest
    # Never the pip path's own message packages, caches or the venv.
    for path in ('interfaces/COLCON_IGNORE', 'interfaces/tf2_msgs/package.xml',
                 'requirements.txt', '.venv/bin/python',
                 'ros2_ws/src/ur_rg2_sim/ur_rg2_sim/__pycache__/camera.cpython-312.pyc',
                 'ros2_ws/src/ur_rg2_sim/ur_rg2_sim.egg-info/PKG-INFO'):
        assert not in_build_context(path), path


def test_entrypoint_sources_the_workspace():
    entrypoint = ROOT / 'docker/ros_entrypoint.sh'
    assert entrypoint.stat().st_mode & 0o111
    subprocess.run(['bash', '-n', str(entrypoint)], check=True)
    assert 'source /ws/install/setup.bash' in entrypoint.read_text()
    assert 'exec "$@"' in entrypoint.read_text()
