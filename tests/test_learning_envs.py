"""The Gymnasium environments of ur_rg2_learning: API, determinism, success flags, vector path.

No ROS: the environments run the sim's plain world core.
"""

import pickle
import warnings

import gymnasium as gym
from gymnasium.utils.env_checker import check_env
import numpy as np
import pytest
from ur_rg2_common.contract import ARM_JOINTS
from ur_rg2_learning import PICK_ID, REACH_ID
import ur_rg2_learning.envs
from ur_rg2_learning.envs import VISION_BALL_NOISE, BallNoise
from ur_rg2_learning.robot import (
    CONTROL_RATE,
    MAX_STEP,
    START_TCP,
    move_target,
    start_joints,
    step_duration,
)
from ur_rg2_learning.scripted import pick_action
from ur_rg2_learning.tasks import BALL_RADIUS, REACH_TOLERANCE
from ur_rg2_motion.kinematics import urdf_velocity_limits
from ur_rg2_sim.trajectory import Point, TrajectoryError, plan, validate

# base_link: the floor is 0.2 m below it (the pedestal), so a ball on it lies at z = -0.17.
BALL = np.array([0.45, -0.2])
BALL_Z = -0.2 + BALL_RADIUS


@pytest.fixture
def make():
    """gym.make for the test; every environment made is closed afterwards."""
    made = []

    def make_env(env_id: str) -> gym.Env:
        made.append(gym.make(env_id))
        return made[-1]

    yield make_env
    for env in made:
        env.close()


def rollout(env: gym.Env, seed: int, steps: int) -> list[np.ndarray]:
    """Return the concatenated observations of ``steps`` seeded random actions."""
    observation, _ = env.reset(seed=seed)
    env.action_space.seed(seed)
    history = [np.concatenate([*observation.values(), [0.0]])]
    for _ in range(steps):
        observation, reward, *_ = env.step(env.action_space.sample())
        history.append(np.concatenate([*observation.values(), [reward]]))
    return history


@pytest.mark.parametrize('env_id', [REACH_ID, PICK_ID])
def test_check_env_passes_without_warnings(env_id, make):
    env = make(env_id)
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        check_env(env.unwrapped)
    assert set(env.observation_space.spaces) == {'observation', 'achieved_goal', 'desired_goal'}
    assert env.action_space.shape == ((3,) if env_id == REACH_ID else (4,))


@pytest.mark.parametrize('env_id', [REACH_ID, PICK_ID])
def test_seeded_episodes_repeat_exactly(env_id, make):
    first, second = make(env_id), make(env_id)
    reference = rollout(first, seed=7, steps=30)
    # Another environment, and the same one after an episode from another seed.
    assert np.array_equal(np.array(rollout(second, seed=7, steps=30)), np.array(reference))
    rollout(first, seed=8, steps=30)
    assert np.array_equal(np.array(rollout(first, seed=7, steps=30)), np.array(reference))
    other = rollout(second, seed=9, steps=0)[0]
    assert not np.array_equal(other, reference[0])  # another seed: another ball and start


def test_reach_success_only_at_the_ball_top(make):
    env = make(REACH_ID)
    top = np.array([*BALL, BALL_Z + BALL_RADIUS])
    still = np.zeros(3, dtype=np.float32)
    observation, info = env.reset(options={'ball_position': BALL, 'tcp_position': top})
    assert info['is_success']
    observation, reward, _, _, info = env.step(still)
    assert info['is_success']
    assert np.allclose(observation['desired_goal'], top)
    assert reward == pytest.approx(-np.linalg.norm(observation['achieved_goal'] - top), abs=1e-6)
    assert -reward < 0.005  # the arm holds the TCP there

    for offset in ((0, 0, 0.05), (0.03, 0, 0), (0, 0, 2.5 * REACH_TOLERANCE)):
        _, info = env.reset(options={'ball_position': BALL, 'tcp_position': top + offset})
        assert not env.step(still)[4]['is_success'], offset

    # compute_reward is vectorised over goals, as HER calls it.
    achieved = np.array([top, top + (0, 0, 0.1)])
    desired = np.array([top, top])
    assert env.unwrapped.compute_reward(achieved, desired, [{}, {}]) == pytest.approx(
        [0.0, -0.1])


def test_pick_success_needs_the_ball_held_and_lifted(make):
    env = make(PICK_ID)
    # The TCP low between the open fingers around the ball, as the motion node's pick grasps.
    options = {'ball_position': BALL, 'tcp_position': [*BALL, BALL_Z + 0.01]}
    close, close_and_lift = np.array([0, 0, 0, -1.0]), np.array([0, 0, 1.0, -1.0])
    open_and_lift = np.array([0, 0, 1.0, 1.0])

    env.reset(options=options)
    for _ in range(5):
        info = env.step(close)[4]
    assert not info['is_success']  # held, still on the floor
    for _ in range(6):
        observation, reward, _, _, info = env.step(close_and_lift)
    assert info['is_success']
    assert observation['achieved_goal'][2] > BALL_Z + 0.1  # the ball came up with the gripper

    env.reset(options=options)
    for _ in range(11):
        observation, _, _, _, info = env.step(open_and_lift)
    assert not info['is_success']  # the open gripper lifts nothing
    assert observation['achieved_goal'][2] == pytest.approx(BALL_Z, abs=0.005)

    goal = observation['desired_goal']
    assert env.unwrapped.compute_reward(np.array([goal, goal - (0, 0, 0.15)]),
                                        np.array([goal, goal]), None) == pytest.approx([0, -1])


def test_two_worker_processes_step_the_same_worlds(make):
    """AsyncVectorEnv: one world per process, as on one core each (or many machines)."""
    envs = gym.vector.AsyncVectorEnv([lambda: gym.make(REACH_ID)] * 2)
    try:
        observations, _ = envs.reset(seed=[3, 4])
        actions = np.tile(np.linspace(-1, 1, 3, dtype=np.float32), (2, 1))
        for _ in range(5):
            observations, rewards, _, _, infos = envs.step(actions)
    finally:
        envs.close()
    assert observations['observation'].shape == (2, 6)
    assert rewards.shape == (2,) and infos['is_success'].shape == (2,)
    for worker, seed in enumerate((3, 4)):  # each worker as one environment in this process
        local = make(REACH_ID)
        local.reset(seed=seed)
        for _ in range(5):
            expected = local.step(actions[0])[0]
        for key in expected:
            assert np.array_equal(observations[key][worker], expected[key]), (worker, key)


def test_a_pickled_environment_is_a_fresh_one_with_the_same_settings(make):
    env = make(REACH_ID).unwrapped
    copy = pickle.loads(pickle.dumps(env))
    try:
        assert copy.world.client != env.world.client  # its own physics world
        assert np.array_equal(rollout(copy, 5, 3)[-1], rollout(env, 5, 3)[-1])
    finally:
        copy.close()


def test_the_scripted_pick_solves_pick_episodes(make):
    """The Pick task is solvable from its observations (the demonstrations train_policy uses)."""
    env = make(PICK_ID)
    successes = 0
    for seed in range(1_000_000, 1_000_005):
        observation, _ = env.reset(seed=seed)
        done = False
        while not done:
            observation, _, terminated, truncated, info = env.step(pick_action(observation))
            done = terminated or truncated
        successes += info['is_success']
    assert successes >= 4


def test_a_step_too_fast_for_the_controller_is_stretched_not_refused(make):
    """The policy node's step timing, judged by the trajectory controller's own check.

    The biggest step out and down from the start turns the shoulder faster in one control
    period than its limit allows: the controller would refuse that goal (the learned Pick
    then lost every ball near the edge of the workspace); stretched, it takes it.
    """
    env = make(PICK_ID).unwrapped
    limits = urdf_velocity_limits(env.world.urdf.read_text())
    start = np.array(START_TCP)
    current = start_joints(env.arm, start)
    target, goal = move_target(env.arm, start, current, np.array([1.0, -1.0, -1.0]))
    assert np.allclose(target, start + MAX_STEP * np.array([1.0, -1.0, -1.0]))

    def controller_plan(duration: float) -> None:
        checked = validate(ARM_JOINTS, [Point(duration, goal)], ARM_JOINTS)
        plan(checked, 0.0, None, current, np.zeros(len(ARM_JOINTS)), limits)

    with pytest.raises(TrajectoryError, match='above its limit'):
        controller_plan(1.0 / CONTROL_RATE)
    duration = step_duration(current, goal, limits)
    assert 1.0 / CONTROL_RATE < duration < 3.0 / CONTROL_RATE
    controller_plan(duration)
    # A step the joints manage in one control period keeps it.
    _, near = move_target(env.arm, start, current, np.full(3, 0.2))
    assert step_duration(current, near, limits) == pytest.approx(1.0 / CONTROL_RATE)


def test_a_target_out_of_reach_keeps_the_target_and_joints(make):
    env = make(PICK_ID).unwrapped
    current = start_joints(env.arm, np.array(START_TCP))
    beyond = np.array([0.78, 0.78, 0.38])  # the step takes it to (0.8, 0.8, 0.4): 1.1 m out
    target, joints = move_target(env.arm, beyond, current, np.ones(3))
    assert np.array_equal(target, beyond) and np.array_equal(joints, current)


def test_free_finger_travel_is_skipped_but_a_grasp_is_stepped(make):
    env = make(PICK_ID)
    env.reset(options={'ball_position': BALL})  # the TCP starts well above the ball
    world = env.unwrapped.world
    steps = world._steps
    world.close_gripper()
    assert world.skip_free_finger_travel()
    assert world._steps == steps and world.gripper_stopped()
    assert world.gripper_opening() == pytest.approx(0.0, abs=1e-6)

    # The open fingers round the ball: closing them is a grasp, stepped in full.
    env.reset(options={'ball_position': BALL, 'tcp_position': [*BALL, BALL_Z + 0.003]})
    world.close_gripper()
    assert not world.skip_free_finger_travel()
    observation, _, _, _, info = env.step(np.array([0, 0, 0, -1.0]))
    assert world.gripper_holds_object()
    assert observation['observation'][6] == pytest.approx(2 * BALL_RADIUS, abs=0.005)


def test_a_grasped_start_holds_the_ball_between_the_fingers(make):
    env = make(PICK_ID)
    observation, info = env.reset(seed=3, options={'grasped': True})
    world = env.unwrapped.world
    assert world.gripper_holds_object()
    tcp, ball, goal = (observation['observation'][0:3], observation['achieved_goal'],
                       observation['desired_goal'])
    assert np.linalg.norm(ball - tcp) < 0.02
    assert goal[2] - 0.15 - 0.005 <= ball[2] <= goal[2] + 0.005  # from the floor to the goal
    for _ in range(5):  # held by the fingers' friction up to the goal
        observation, _, _, _, info = env.step(np.array([0, 0, 1.0, -1.0]))
    assert info['is_success']
    assert observation['achieved_goal'][2] > BALL_Z + 0.1


def test_a_share_of_episodes_start_grasped():
    env = gym.make(PICK_ID, grasped_share=0.5)
    try:
        held = [env.reset(seed=seed)[0]['achieved_goal'][2] > BALL_Z + 0.005
                or env.unwrapped.world.gripper_holds_object() for seed in range(20)]
    finally:
        env.close()
    assert 3 <= sum(held) <= 17


def test_an_over_ball_start_has_the_open_fingers_over_the_ball_on_the_floor(make):
    env = make(PICK_ID)
    for seed in range(3):
        observation, info = env.reset(seed=seed, options={'over_ball': True})
        tcp, ball = observation['observation'][0:3], observation['achieved_goal']
        assert ball[2] == pytest.approx(BALL_Z, abs=0.002)  # lying on the floor
        assert np.linalg.norm(ball[:2] - tcp[:2]) < 0.02
        assert 0.0 < tcp[2] - ball[2] < 0.1
        assert observation['observation'][6] > 0.1  # open
        assert not info['is_success']
    # From there the scripted pick closes, lifts and holds it.
    for _ in range(60):
        observation, _, _, _, info = env.step(pick_action(observation))
    assert info['is_success']


def test_shares_of_episodes_start_grasped_and_over_the_ball():
    env = gym.make(PICK_ID, grasped_share=0.3, over_ball_share=0.4)
    starts = []
    try:
        for seed in range(30):
            observation = env.reset(seed=seed)[0]
            tcp, ball = observation['observation'][0:3], observation['achieved_goal']
            held = env.unwrapped.world.gripper_holds_object()
            starts.append('grasped' if held else
                          'over' if np.linalg.norm(ball[:2] - tcp[:2]) < 0.02 else 'free')
    finally:
        env.close()
    assert all(3 <= starts.count(kind) <= 20 for kind in ('grasped', 'over', 'free')), starts


def test_ball_noise_perturbs_what_is_seen_of_the_ball_and_nothing_else():
    true, noisy = gym.make(PICK_ID), ur_rg2_learning.envs.make(PICK_ID, 0.005)
    try:
        assert isinstance(noisy, BallNoise)
        seen, truth = [noisy.reset(seed=7)[0]], [true.reset(seed=7)[0]]
        offset = seen[0]['desired_goal'] - truth[0]['desired_goal']
        for _ in range(30):
            action = pick_action(truth[-1])
            a, b = noisy.step(action), true.step(action)
            assert a[1:] == b[1:]  # rewards, ends and success: the true ones
            seen.append(a[0])
            truth.append(b[0])
        errors = []
        for previous, s, t in zip(seen, seen[1:], truth[1:]):
            ball = s['observation'][7:10]
            assert np.allclose(s['observation'][:7], t['observation'][:7])  # TCP, gripper
            assert np.allclose(s['achieved_goal'], ball)
            assert np.allclose(s['observation'][10:13], ball - s['observation'][:3], atol=1e-6)
            assert np.allclose(s['observation'][13:16],
                               (ball - previous['achieved_goal']) * CONTROL_RATE, atol=1e-4)
            assert np.allclose(s['desired_goal'] - t['desired_goal'], offset, atol=1e-6)
            errors.append(ball - t['achieved_goal'])
        assert 0.003 < np.std(errors) < 0.008  # 5 mm per axis
        # Repeats under a seed; the episode placed as without noise.
        again = noisy.reset(seed=7)[0]
        assert np.array_equal(again['achieved_goal'], seen[0]['achieved_goal'])
        assert np.allclose(again['observation'][:3], truth[0]['observation'][:3])
    finally:
        true.close()
        noisy.close()
    assert 0.001 < VISION_BALL_NOISE < 0.002
    with pytest.raises(ValueError, match='for Pick'):
        ur_rg2_learning.envs.make(REACH_ID, 0.001)
    assert not isinstance(ur_rg2_learning.envs.make(PICK_ID, 0.0), BallNoise)
