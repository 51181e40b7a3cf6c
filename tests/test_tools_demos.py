"""demos: N pick episodes of the running graph recorded to an MCAP file that to_lerobot exports.

Plain: the episode loop (ur_rg2_tools.demos) with a stand-in driver. Through the contract: the
graph as the README runs it (scripts/run, headless), ``ros2 run ur_rg2_tools demos`` for two
episodes, the file read back with the project's own reader and exported by to_lerobot; and a
bad input that is one error line and exit code 1.
"""

import argparse
import subprocess

import numpy as np
from test_bringup import ROOT
from test_bringup_graph import PARAMS_FILE
from ur_rg2_common.contract import EPISODE_FAILURE, EPISODE_START, EPISODE_SUCCESS
from ur_rg2_tools.demos import (
    PLACEMENT_TRIES,
    Scene,
    Tally,
    format_duration,
    run_episodes,
)
from ur_rg2_tools.recording_frames import Reader, read_streams
from ur_rg2_tools.to_lerobot import main as to_lerobot
from ur_rg2_vision.placement import REACH, Camera
import yaml

# The sim's default camera (ur_rg2_sim settings) at 640x480, 60 degrees field of view.
K = np.array([[554.26, 0, 320], [0, 554.26, 240], [0, 0, 1]])
SCENE = Scene(Camera((1.0, 1.0, 1.0), (0.4, 0.0, 0.0), K, 640, 480), 0.03, 'ur5')


class StandIn:
    """A driver that logs what the loop asks; ``unseen`` placements are not seen."""

    def __init__(self, outcomes, unseen=0) -> None:
        self.calls: list = []
        self.outcomes = list(outcomes)
        self.unseen = unseen

    def place_ball(self, position):
        self.calls.append(('place', position))

    def home(self):
        self.calls.append('home')

    def drop(self):
        self.calls.append('drop')

    def see_ball(self):
        self.unseen -= 1
        return self.unseen < 0

    def pick(self):
        self.calls.append('pick')
        return self.outcomes.pop(0), 'picked'


def options(episodes: int, seed: int = 3) -> argparse.Namespace:
    return argparse.Namespace(episodes=episodes, seed=seed)


def test_each_episode_places_the_ball_in_reach_goes_home_and_picks():
    driver, lines = StandIn([True, False, True]), []
    tally = run_episodes(driver, SCENE, options(3), lambda: False, lines.append)
    assert (tally.done, tally.successes) == (3, 2)
    assert [c for c in driver.calls if not isinstance(c, tuple)] == [
        'drop', 'home', 'pick'] * 3 + ['drop', 'home']
    places = [c[1] for c in driver.calls if isinstance(c, tuple)]
    low, high = REACH['ur5']
    assert all(low <= np.hypot(x, y) <= high and z == 0.03 for x, y, z in places)
    assert len(set(places)) == 3
    assert lines[-1].startswith('episode 3/3: 2 successes (67%), ')
    # The same seed, the same placements.
    again = StandIn([True] * 3)
    run_episodes(again, SCENE, options(3), lambda: False, lines.append)
    assert [c for c in again.calls if isinstance(c, tuple)] == [('place', p) for p in places]


def test_a_ball_never_seen_is_no_episode_and_a_stop_ends_after_the_episode():
    driver, lines = StandIn([True], unseen=PLACEMENT_TRIES), []
    tally = run_episodes(driver, SCENE, options(3), lambda: driver.calls.count('pick') >= 1,
                         lines.append)
    assert (tally.done, tally.unseen) == (1, 1)
    assert sum(isinstance(c, tuple) for c in driver.calls) == PLACEMENT_TRIES + 1
    assert 'not seen' in lines[-1]


def test_the_progress_line_gives_the_rate_and_the_time_left():
    tally = Tally(50, started=0.0)
    assert tally.line(now=1.0) == 'episode 0/50: 0 successes'
    for success in (True, True, False, True):
        tally.add(success)
    assert tally.line(now=40.0) == ('episode 4/50: 3 successes (75%), 10.0 s per episode, '
                                    'ETA 7 min 40 s')
    assert tally.summary(now=40.0) == '4 of 50 episodes done, 3 successes, in 40 s'
    assert format_duration(3725) == '1 h 02 min' and format_duration(9.6) == '10 s'


# -- through the contract -------------------------------------------------------------------------

def test_bad_input_is_one_error_line_and_exit_code_1(ros_graph, tmp_path):
    taken = tmp_path / 'taken.mcap'
    taken.write_bytes(b'mine')
    for arguments, message in (
            (['-o', str(taken), '--episodes', '2'], f'demos: {taken} exists'),
            (['-o', str(tmp_path / 'a.mcap'), '--episodes', '0'],
             'demos: --episodes must be at least 1, not 0'),
            # No graph on this test's domain.
            (['-o', str(tmp_path / 'b.mcap'), '--episodes', '1', '--timeout-s', '2'],
             'demos: no graph: the sim (ur_rg2_sim parameters) did not answer within 2 s')):
        run = subprocess.run(['ros2', 'run', 'ur_rg2_tools', 'demos', *arguments],
                             capture_output=True, text=True, env=ros_graph.env, timeout=120)
        assert run.returncode == 1, run
        assert run.stderr.strip().splitlines()[-1].startswith(message), run.stderr
        assert 'Traceback' not in run.stderr
    assert taken.read_bytes() == b'mine'
    assert not (tmp_path / 'b.mcap').exists()


def test_two_episodes_recorded_from_the_graph_export_as_two(ros_graph, tmp_path):
    params = yaml.safe_load(PARAMS_FILE.read_text())
    params['/**/ur_rg2_sim']['ros__parameters'].update(camera_width=320, camera_height=240)
    params_file = tmp_path / 'graph.yaml'
    params_file.write_text(yaml.safe_dump(params))
    log_path, output = tmp_path / 'graph.log', tmp_path / 'demos.mcap'
    with log_path.open('w') as log:
        graph = subprocess.Popen(
            [str(ROOT / 'scripts/run'), 'camera_rate:=10.0', 'port:=0',
             f'params_file:={params_file}'],
            stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=ros_graph.env)
    try:
        demos = subprocess.run(
            ['ros2', 'run', 'ur_rg2_tools', 'demos', '-o', str(output), '--episodes', '2',
             '--seed', '1', '--timeout-s', '180'],
            capture_output=True, text=True, env=ros_graph.env, timeout=1500)
        assert demos.returncode == 0, (demos, log_path.read_text()[-3000:])
        assert graph.poll() is None, log_path.read_text()
    finally:
        graph.terminate()
        try:
            graph.wait(timeout=60)
        finally:
            graph.kill()
    lines = demos.stdout.splitlines()
    assert lines[-1].startswith('demos: 2 of 2 episodes done, '), demos.stdout
    assert str(output) in lines[-1]
    reader = Reader(output, '')
    try:
        markers = [value for _, value in read_streams(reader).markers]
    finally:
        reader.close()
    assert markers.count(EPISODE_START) == 2, markers
    assert markers.count(EPISODE_SUCCESS) + markers.count(EPISODE_FAILURE) == 2, markers
    dataset = tmp_path / 'dataset'
    assert to_lerobot([str(output), '-o', str(dataset)]) == 0
    info = yaml.safe_load((dataset / 'meta' / 'info.json').read_text())
    assert info['total_episodes'] == 2
