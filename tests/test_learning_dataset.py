"""train_policy --dataset: a LeRobot data set's frames as Pick steps, cloned into a policy.

The data set is made here as to_lerobot writes one (meta/info.json of codebase v3.0, the
frames in data/chunk-000/file-000.parquet; no video: the training reads none): the scripted
pick run in the Pick environment, each frame its joints, the RG2's opening and the ball in the
default camera's optical frame, as vision reports it.
"""

import json
from pathlib import Path
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from ur_rg2_common.camera_pose import optical_rotation
from ur_rg2_common.contract import ARM_JOINTS, GRIPPER_JOINTS
from ur_rg2_learning import PICK_ID
from ur_rg2_learning.actor import Actor
from ur_rg2_learning.dataset_demos import (
    CAMERA_LOOK_AT,
    CAMERA_POSITION,
    HOLD_STEPS,
    DatasetError,
    dataset_demonstrations,
    gripper_commands,
    read_dataset,
    split_step,
)
from ur_rg2_learning.robot import MAX_STEP
from ur_rg2_learning.scripted import pick_action

BIN = Path(sys.executable).parent
EPISODES = 3


def scripted_frames(env: gym.Env, seed: int) -> tuple[np.ndarray, np.ndarray, bool]:
    """Return one scripted pick's states (n, 7), environment states (n, 4) and its success."""
    base = env.unwrapped
    rotation = optical_rotation(CAMERA_POSITION, CAMERA_LOOK_AT)
    lift = np.array([0.0, 0.0, base.world.pedestal_height])
    observation, _ = env.reset(seed=seed)
    states, environments, success, after = [], [], False, 0
    for _ in range(80):
        sample = base.world.joint_states()
        positions = dict(zip(sample.names, sample.positions))
        states.append([*(positions[j] for j in ARM_JOINTS),
                       sum(positions[j] for j in GRIPPER_JOINTS)])
        ball = observation['achieved_goal'].astype(float) + lift  # the world frame
        environments.append([*rotation.T @ (ball - CAMERA_POSITION), 1.0])
        if after > 2:  # a few frames beyond the goal, the ball held
            break
        observation, reward, _, _, info = env.step(pick_action(observation))
        success = bool(info['is_success'])
        after += reward == 0.0
    return np.array(states, np.float32), np.array(environments, np.float32), success


def write_dataset(root: Path, episodes: list[tuple[np.ndarray, np.ndarray, bool]],
                  fps: int = 10, version: str = 'v3.0') -> Path:
    """Write a data set of ``episodes`` as to_lerobot lays it out (without the video)."""
    columns: dict[str, list] = {}
    for index, (states, environments, success) in enumerate(episodes):
        count = len(states)
        done = np.arange(count) == count - 1
        rows = {'observation.state': list(states),
                'action': list(np.concatenate([states[1:], states[-1:]])),
                'observation.environment_state': list(environments),
                'next.done': list(done), 'next.success': list(done & success),
                'frame_index': list(range(count)), 'episode_index': [index] * count}
        for key, values in rows.items():
            columns.setdefault(key, []).extend(values)
    table = pa.table({key: (pa.array([np.asarray(v, np.float32).tolist() for v in values],
                                     pa.list_(pa.float32(), len(values[0])))
                            if np.ndim(values[0]) else pa.array(values))
                      for key, values in columns.items()})
    (root / 'data' / 'chunk-000').mkdir(parents=True)
    pq.write_table(table, root / 'data' / 'chunk-000' / 'file-000.parquet')
    (root / 'meta').mkdir()
    vector = {'dtype': 'float32', 'names': None}
    info = {'codebase_version': version, 'fps': fps, 'total_episodes': len(episodes),
            'features': {'observation.state': dict(vector, shape=[7]),
                         'action': dict(vector, shape=[7]),
                         'observation.environment_state': dict(vector, shape=[4])}}
    (root / 'meta' / 'info.json').write_text(json.dumps(info))
    return root


@pytest.fixture(scope='module')
def scripted_episodes():
    env = gym.make(PICK_ID)
    try:
        return [scripted_frames(env, 900_000 + i) for i in range(EPISODES)]
    finally:
        env.close()


def test_frames_become_the_steps_the_environment_takes(tmp_path, scripted_episodes):
    assert all(success for _, _, success in scripted_episodes)  # whole picks
    dataset = read_dataset(write_dataset(tmp_path / 'set', scripted_episodes))
    assert dataset.fps == 10 and len(dataset.states) == EPISODES
    assert dataset.successes == [True] * EPISODES
    env = gym.make(PICK_ID)
    try:
        steps, meta = dataset_demonstrations(dataset.path, env)
    finally:
        env.close()
    assert meta['dataset']['episodes'] == meta['dataset']['episodes_used'] == EPISODES
    count = len(steps['action'])
    assert meta['dataset']['steps'] == count and int(steps['done'].sum()) == EPISODES
    assert steps['observation'].shape == (count, 16) and steps['action'].shape == (count, 4)
    # The ball back in base_link where the environment had it; the goal 15 cm above it.
    first_ball = scripted_episodes[0][1][0]
    assert first_ball[3] == 1.0
    observation = steps['observation'][0]
    env = gym.make(PICK_ID)
    try:
        truth, _ = env.reset(seed=900_000)
    finally:
        env.close()
    np.testing.assert_allclose(observation[7:10], truth['observation'][7:10], atol=1e-4)
    np.testing.assert_allclose(observation[:3], truth['observation'][:3], atol=2e-3)
    np.testing.assert_allclose(steps['desired_goal'][0], truth['desired_goal'], atol=1e-4)
    # Moves as the TCP went: the next observation's TCP is MAX_STEP * action further, within
    # the action's bounds (faster moves are split), and no pause (no move, the RG2 unchanged).
    moved = (steps['next_observation'][:, :3] - steps['observation'][:, :3]) / MAX_STEP
    np.testing.assert_allclose(steps['action'][:, :3], moved, atol=1e-4)
    assert np.abs(steps['action']).max() <= 1.0
    recorded = np.ones(count, dtype=bool)
    for end in np.flatnonzero(steps['done']):
        recorded[end + 1 - HOLD_STEPS:end + 1] = False
    still = np.abs(steps['action'][:, :3]).max(axis=1) < 0.02
    unchanged = np.r_[False, steps['action'][1:, 3] == steps['action'][:-1, 3]]
    assert not np.any(still & unchanged & recorded)
    # Each episode opens, then closes on the ball and keeps it closed; the lift is rewarded.
    grips = steps['action'][:, 3]
    assert grips[0] == 1.0 and -1.0 in grips and set(grips) <= {-1.0, 1.0}
    assert steps['reward'].max() == 0.0 and steps['reward'].min() == -1.0
    # After the lift each episode holds the ball still at the goal, as the environment goes on.
    for end in np.flatnonzero(steps['done']):
        held = slice(end + 1 - HOLD_STEPS, end + 1)
        assert steps['action'][held].tolist() == [[0.0, 0.0, 0.0, -1.0]] * HOLD_STEPS
        assert np.all(steps['reward'][held] == 0.0)


def test_a_fast_move_is_split_into_steps_within_the_bounds():
    def observation(tcp, ball):
        state = np.zeros(16, np.float32)
        state[:3], state[7:10], state[10:13] = tcp, ball, np.subtract(ball, tcp)
        return {'observation': state, 'achieved_goal': np.float32(ball),
                'desired_goal': np.float32([0.4, 0.0, -0.02])}

    ball = [0.4, 0.0, -0.17]
    start, end = observation([0.5, 0.1, 0.0], ball), observation([0.5, -0.02, -0.03], ball)
    steps = split_step(start, end, np.array([0.0, -1.0, -0.6, 1.0], np.float32))
    assert len(steps) == 3 and steps[0][0] is start and steps[-1][2] is end
    for (before, action, after) in steps:
        np.testing.assert_allclose(action, [0.0, -0.8, -0.2, 1.0], atol=1e-6)
        np.testing.assert_allclose(after['observation'][:3] - before['observation'][:3],
                                   action[:3] * MAX_STEP, atol=1e-6)
    middle = steps[1][0]['observation']
    np.testing.assert_allclose(middle[3:6], [0.0, -0.4, -0.1], atol=1e-6)  # m/s
    np.testing.assert_allclose(middle[10:13], np.subtract(ball, middle[:3]), atol=1e-6)
    slow = split_step(start, observation([0.5, 0.08, 0.0], ball), np.zeros(4, np.float32))
    assert len(slow) == 1 and np.allclose(slow[0][1], [0.0, -0.4, 0.0, 0.0])


def test_gripper_commands_follow_the_fingers():
    openings = np.array([0.11, 0.11, 0.09, 0.06, 0.058, 0.058, 0.08, 0.11, 0.11])
    assert gripper_commands(openings).tolist() == [
        False, True, True, True, True, False, False, False, False]


def test_train_policy_dataset_writes_a_loadable_cloned_policy(tmp_path, scripted_episodes):
    root = write_dataset(tmp_path / 'set', scripted_episodes)
    out = tmp_path / 'policy'
    trained = subprocess.run(
        [str(BIN / 'train_policy'), '--dataset', str(root), '--bc-epochs', '20',
         '--eval-episodes', '1', '--final-episodes', '1', '--out', str(out)],
        capture_output=True, text=True, timeout=300)
    assert trained.returncode == 0, trained.stderr
    assert 'cloned ' in trained.stdout and f'of {EPISODES} episodes, 20 epochs' in trained.stdout
    actor = Actor.load(out)
    assert actor.env_id == PICK_ID
    meta = actor.meta
    assert meta['method'].startswith('behaviour cloning (20 epochs) of the data set set')
    assert meta['timesteps'] == 0 and meta['rl_updates'] == 0
    assert meta['dataset']['episodes'] == EPISODES and meta['dataset']['path'] == str(root)
    assert meta['cloned_before_rl'] == meta['dataset']['steps']
    assert 0.0 <= meta['held_out']['final_success'] <= 1.0
    env = gym.make(PICK_ID)
    try:
        observation, _ = env.reset(seed=1)
        action = actor(observation)
    finally:
        env.close()
    assert action.shape == (4,) and np.all(np.abs(action) <= 1.0)


@pytest.mark.parametrize('case', ['missing', 'not_lerobot', 'old_version', 'no_episodes',
                                  'other_robot', 'odd_fps'])
def test_train_policy_refuses_a_bad_dataset(tmp_path, case):
    root = tmp_path / 'set'
    states = np.zeros((3, 7), np.float32)
    environments = np.zeros((3, 4), np.float32)
    if case == 'not_lerobot':
        root.mkdir()
        (root / 'notes.txt').write_text('hello')
    elif case == 'old_version':
        write_dataset(root, [(states, environments, False)], version='v2.1')
    elif case == 'no_episodes':
        write_dataset(root, [(states, environments, False)])
        table = pq.read_table(root / 'data' / 'chunk-000' / 'file-000.parquet')
        pq.write_table(table.slice(0, 0), root / 'data' / 'chunk-000' / 'file-000.parquet')
    elif case == 'other_robot':
        write_dataset(root, [(states, environments, False)])
        info = json.loads((root / 'meta' / 'info.json').read_text())
        info['features']['observation.state']['shape'] = [14]
        (root / 'meta' / 'info.json').write_text(json.dumps(info))
    elif case == 'odd_fps':
        write_dataset(root, [(states, environments, False)], fps=15)
    expected = {'missing': 'no such directory', 'not_lerobot': 'not a LeRobot data set',
                'old_version': "codebase version 'v2.1'", 'no_episodes': 'no episodes',
                'other_robot': 'no observation.state of 7 values', 'odd_fps': '15 fps'}[case]
    with pytest.raises(DatasetError, match=expected):
        read_dataset(root)
    out = tmp_path / 'policy'
    refused = subprocess.run(
        [str(BIN / 'train_policy'), '--dataset', str(root), '--out', str(out)],
        capture_output=True, text=True, timeout=120)
    assert refused.returncode == 2, refused.stderr
    assert f'train_policy: {root}' in refused.stderr and expected in refused.stderr
    assert 'Traceback' not in refused.stderr and not out.exists()


def test_a_dataset_where_the_ball_is_never_seen_gives_no_steps(tmp_path):
    states = np.zeros((5, 7), np.float32)
    root = write_dataset(tmp_path / 'set', [(states, np.zeros((5, 4), np.float32), False)])
    env = gym.make(PICK_ID)
    try:
        with pytest.raises(DatasetError, match='none of its 1 episodes gives a step'):
            dataset_demonstrations(root, env)
    finally:
        env.close()


def test_dataset_options_are_checked():
    for extra in (['--env', 'UrRg2Reach-v0'], ['--timesteps', '10'], ['--demos', '2'],
                  ['--bc-epochs', '0'], ['--finetune-steps', '-1']):
        refused = subprocess.run(
            [str(BIN / 'train_policy'), '--dataset', 'x', '--out', 'y', *extra],
            capture_output=True, text=True, timeout=60)
        assert refused.returncode == 2 and 'Traceback' not in refused.stderr, extra
