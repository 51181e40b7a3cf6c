"""The policy node's episode logic without ROS: observations, the end of an episode, steps."""

import gymnasium as gym
import numpy as np
import pytest
from ur_rg2_common.contract import RG2_MAX_OPENING
from ur_rg2_learning import EPISODE_STEPS, PICK_ID
from ur_rg2_learning.episode import LOST_STEPS, Episode, Outcome, start_episode
from ur_rg2_learning.robot import START_TCP, start_joints
from ur_rg2_learning.tasks import BALL_RADIUS, pick_goal

BALL = np.array([0.45, -0.2, -0.2 + BALL_RADIUS])  # base_link, on the floor


@pytest.fixture(scope='module')
def arm():
    """Return the UR5 on its pedestal, as the Pick environment builds it."""
    env = gym.make(PICK_ID)
    yield env.unwrapped.arm
    env.close()


def start(arm, picks: bool) -> tuple[Episode, np.ndarray]:
    joints = start_joints(arm, np.array(START_TCP))
    return Episode(picks, np.array(START_TCP), joints, pick_goal(BALL), BALL_RADIUS, 0.0), joints


def test_reach_ends_at_the_ball_top_or_after_its_steps(arm):
    episode, joints = start(arm, picks=False)
    observation = episode.observe(arm, joints, None, lambda: BALL)
    assert set(observation) == {'observation', 'achieved_goal', 'desired_goal'}
    assert np.allclose(observation['desired_goal'], BALL + (0, 0, BALL_RADIUS))
    tcp = arm.tcp_pose(joints)[:3, 3]
    outcome = episode.observe(arm, joints, None, lambda: tcp - (0, 0, BALL_RADIUS + 0.005))
    assert outcome == Outcome('reached the ball: TCP 5 mm from its top after 0 steps', True)
    episode.step = EPISODE_STEPS['UrRg2Reach-v0']
    outcome = episode.observe(arm, joints, None, lambda: BALL)
    assert not outcome.reached and outcome.text.startswith('not reached after 50 steps')


def test_a_pick_step_moves_the_target_and_changes_the_gripper_once(arm):
    episode, joints = start(arm, picks=True)
    limits = np.full(6, 3.0)
    step = episode.act(np.array([0.0, 0.0, -1.0, -1.0]), arm, joints, limits, RG2_MAX_OPENING)
    assert step.gripper == 0.0 and episode.closed and episode.step == 1
    assert episode.target == pytest.approx(np.add(START_TCP, (0, 0, -0.05)))
    assert step.duration == pytest.approx(0.1)
    assert np.allclose(arm.tcp_pose(step.joints)[:3, 3], episode.target, atol=1e-6)
    step = episode.act(np.array([0.0, 0.0, 0.0, -0.5]), arm, step.joints, limits,
                       RG2_MAX_OPENING)
    assert step.gripper is None  # still closed
    step = episode.act(np.array([0.0, 0.0, 0.0, 0.5]), arm, step.joints, limits,
                       RG2_MAX_OPENING)
    assert step.gripper == RG2_MAX_OPENING and not episode.closed


def test_a_held_ball_moves_with_the_tcp_and_an_unseen_one_ends_the_episode(arm):
    episode, joints = start(arm, picks=True)
    tcp = arm.tcp_pose(joints)[:3, 3]
    seen = tcp - (0, 0, 0.003)
    episode.closed = True
    observation = episode.observe(arm, joints, 2 * BALL_RADIUS, lambda: seen)
    assert np.allclose(observation['achieved_goal'], seen)

    def unseen():
        raise ValueError('no ball seen')

    # Held: where the camera no longer sees it, it is where the TCP holds it.
    observation = episode.observe(arm, joints, 2 * BALL_RADIUS, unseen)
    assert np.allclose(observation['achieved_goal'], seen)

    episode, joints = start(arm, picks=True)
    episode.observe(arm, joints, RG2_MAX_OPENING, lambda: BALL)
    for _ in range(LOST_STEPS):  # hidden by the arm for a while: where it was last seen
        observation = episode.observe(arm, joints, RG2_MAX_OPENING, unseen)
        assert np.allclose(observation['achieved_goal'], BALL)
    with pytest.raises(ValueError, match='no longer seen'):
        episode.observe(arm, joints, RG2_MAX_OPENING, unseen)


@pytest.mark.parametrize('picks', [False, True])
def test_an_episode_starts_with_a_move_to_the_start_pose_unless_the_ball_is_out_of_reach(
        arm, picks):
    now = start_joints(arm, np.array(START_TCP)) + 0.2  # the arm somewhere else
    limits = np.full(6, 3.0)
    episode, trajectory = start_episode(picks, arm, now, BALL, BALL_RADIUS, limits)
    assert np.allclose(arm.tcp_pose(trajectory.positions[-1])[:3, 3], START_TCP, atol=1e-6)
    assert np.allclose(episode.target, START_TCP) and episode.step == 0
    assert np.allclose(episode.goal, pick_goal(BALL))
    far = np.array([1.5, -0.2, BALL[2]])
    with pytest.raises(ValueError, match='the ball is out of reach'):
        start_episode(picks, arm, now, far, BALL_RADIUS, limits)
