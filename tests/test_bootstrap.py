"""scripts/bootstrap: an environment it has set up stays up to date for every requirements file.

scripts/test has run it before the suite, so every later ``scripts/run`` or ``scripts/bootstrap``
has nothing to do; ``--check`` says so without changing anything.
"""

from pathlib import Path
import shutil
import subprocess
import sys

import pytest

ROOT = Path(__file__).resolve().parents[1]
BOOTSTRAP = ROOT / 'scripts' / 'bootstrap'


@pytest.mark.parametrize('requirements', ['requirements-dev.txt', 'requirements.txt'])
def test_the_set_up_environment_is_up_to_date_for_each_file(requirements):
    checked = subprocess.run([str(BOOTSTRAP), '--check', requirements], capture_output=True,
                             text=True, timeout=60)
    assert checked.returncode == 0, checked.stderr
    assert checked.stderr == ''


def test_check_of_a_clone_never_set_up_says_so_and_creates_nothing(tmp_path):
    # A checkout of the scripts and the files the set-up reads, without a .venv.
    shutil.copytree(ROOT / 'scripts', tmp_path / 'scripts')
    for name in ('requirements.txt', 'interfaces', 'ros2_ws/src/ur_rg2_interfaces',
                 'ros2_ws/src/ur_rg2_common'):
        copy = shutil.copytree if (ROOT / name).is_dir() else shutil.copy
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        copy(ROOT / name, tmp_path / name)
    checked = subprocess.run([str(tmp_path / 'scripts' / 'bootstrap'), '--check'],
                             capture_output=True, text=True, timeout=60)
    assert checked.returncode == 1, checked.stderr
    assert checked.stderr == (f'bootstrap: {tmp_path / ".venv"} is not up to date for '
                              'requirements.txt (scripts/bootstrap requirements.txt updates it)\n')
    assert not (tmp_path / '.venv').exists()


@pytest.mark.parametrize('package', ['tf2_msgs', 'control_msgs', 'composition_interfaces',
                                     'ur_rg2_interfaces'])
def test_the_message_packages_are_built_for_c_and_python_only(package):
    # scripts/build-interfaces builds them into the venv that runs the suite.
    lib = Path(sys.prefix) / 'lib'
    if not (Path(sys.prefix) / 'share' / 'ur_rg2_interfaces.sha256').is_file():
        pytest.skip('a ROS install: the distribution built these packages')
    built = {path.name for path in lib.glob(f'lib{package}__*.so')}
    assert {f'lib{package}__rosidl_{kind}.so' for kind in (
        'generator_c', 'generator_py', 'typesupport_c', 'typesupport_fastrtps_c',
        'typesupport_introspection_c')} <= built
    assert not {name for name in built if '_cpp' in name}, sorted(built)
