"""ur_rg2_common.entry: a node stopped while its modules still load ends quietly, exit code 0.

What ``ros2 launch`` does to a node that is still importing when another node fails: SIGINT.
"""

import signal
import subprocess
import sys

from conftest import wait_for

START = ('import sys; from ur_rg2_common.entry import run_main; '
         'sys.exit(run_main(sys.argv[1]))')


def start(tmp_path, module: str, source: str) -> subprocess.Popen:
    (tmp_path / f'{module}.py').write_text(source)
    return subprocess.Popen([sys.executable, '-c', START, module], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def interrupt_while_loading(tmp_path, module: str, loading: str, main: str) -> tuple[int, str]:
    """SIGINT ``module`` while its ``loading`` source runs; return its exit code and stderr.

    ``loading`` sleeps 60 s, as a heavy import would: the SIGINT must cut it short. The test
    waits for it to begin on a file, with a deadline.
    """
    began = tmp_path / 'loading'
    node = start(tmp_path, module, 'import pathlib, time\n'
                 f'pathlib.Path({str(began)!r}).touch()\n{loading}{main}')
    try:
        wait_for(began.exists, 30.0, 'the node module to start loading')
        node.send_signal(signal.SIGINT)
        _, err = node.communicate(timeout=30)
    finally:
        node.kill()
    return node.returncode, err


def test_a_sigint_while_the_node_module_loads_ends_it_with_no_traceback(tmp_path):
    code, err = interrupt_while_loading(tmp_path, 'slow_node', 'time.sleep(60)\n',
                                        'def main():\n    return 3\n')
    assert code == 0
    assert 'Traceback' not in err, err


def test_the_node_main_runs_and_its_exit_code_is_kept(tmp_path):
    node = start(tmp_path, 'quick_node', 'def main():\n    print("running")\n    return 3\n')
    out, _ = node.communicate(timeout=30)
    assert (node.returncode, out) == (3, 'running\n')


def test_a_sigint_swallowed_while_the_node_module_loads_still_stops_it(tmp_path):
    # Python drops a KeyboardInterrupt raised in a weakref callback (one of importlib's module
    # locks has one); the module below drops it the same way.
    ran = tmp_path / 'main_ran'
    code, err = interrupt_while_loading(
        tmp_path, 'swallowing_node',
        'try:\n    time.sleep(60)\nexcept KeyboardInterrupt:\n    pass\n',
        f'def main():\n    pathlib.Path({str(ran)!r}).touch()\n    return 3\n')
    assert code == 0
    assert not ran.exists(), 'the node started after the stop'
    assert 'Traceback' not in err, err
