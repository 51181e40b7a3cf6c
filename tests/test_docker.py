"""docker/Dockerfile without a Docker engine: hadolint, and in step with the pinned versions."""

from pathlib import Path
import re
import shutil
import subprocess
import sys

ROOT = Path(__file__).resolve().parents[1]
DOCKERFILE = ROOT / 'docker/Dockerfile'


def pins(path: Path) -> dict[str, str]:
    """Return ``{name: version}`` of the ``name==version`` lines of a requirements file."""
    found = {}
    for line in path.read_text().splitlines():
        match = re.fullmatch(r'([A-Za-z0-9_.-]+)==(\S+)', line.split('#')[0].strip())
        if match:
            found[match[1].lower()] = match[2]
    return found


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


def test_image_installs_the_pinned_versions():
    text = DOCKERFILE.read_text()
    assert 'COPY requirements.txt /tmp/requirements.txt' in text
    # Run the Dockerfile's own filter on the real file, the way the image build does.
    pattern = re.search(r"grep -vE '([^']+)' /tmp/requirements\.txt", text)[1]
    kept = subprocess.run(['grep', '-vE', pattern, str(ROOT / 'requirements.txt')],
                          capture_output=True, text=True, check=True).stdout
    installed = {name: version for name, version in pins(ROOT / 'requirements.txt').items()
                 if re.search(rf'^{re.escape(name)}==', kept, re.MULTILINE | re.IGNORECASE)}
    left_out = set(pins(ROOT / 'requirements.txt')) - set(installed)
    # Only what the base image provides: ROS from apt, and Ubuntu's setuptools for colcon.
    assert all(name.startswith('ros-jazzy-') or name == 'setuptools' for name in left_out)
    assert {'pybullet', 'example-robot-data', 'numpy', 'opencv-python-headless'} <= set(
        installed)
    assert re.search(r'pip install .*-r /tmp/requirements-image\.txt', text)
    # No version written into the Dockerfile itself that could drift from the pins.
    assert not re.findall(r'\b[A-Za-z][\w.-]*==\d', text)


def test_copied_files_exist_and_the_entrypoint_sources_the_workspace():
    text = DOCKERFILE.read_text()
    for source in re.findall(r'^COPY (\S+) ', text, re.MULTILINE):
        assert (ROOT / source).exists(), f'COPY {source}: no such file in the repository'
        # The build context is filtered by the .dockerignore next to the Dockerfile.
        assert f'!{source}' in (ROOT / 'docker/Dockerfile.dockerignore').read_text()
    entrypoint = ROOT / 'docker/ros_entrypoint.sh'
    assert entrypoint.stat().st_mode & 0o111
    subprocess.run(['bash', '-n', str(entrypoint)], check=True)
    assert 'source /ws/install/setup.bash' in entrypoint.read_text()
    assert 'exec "$@"' in entrypoint.read_text()
