"""A LeRobot data set (``to_lerobot``'s, codebase v3.0) as Pick demonstrations. No torch, no ROS.

``train_policy --dataset DIR`` clones the Pick environment's action from these steps and may
fine-tune with them in the replay buffer (ur_rg2_learning.training_run). A frame of the data set
holds the six arm joints and the RG2's opening (``observation.state``), the ball as vision saw
it in the camera's optical frame and whether it was seen (``observation.environment_state``)
and the next frame's state (``action``). Each frame becomes the step the policy node would
have taken there (ur_rg2_learning.episode, so the observation is built as the node builds it
in the graph):

* observation: the TCP by forward kinematics of the joints (the environment's arm, on its
  pedestal), its velocity from the last frame, the opening, and the ball taken from the
  optical frame into ``base_link`` with the camera's pose (``--camera-position`` and
  ``--camera-look-at``, the sim's defaults unless the recording had others); while the
  closed fingers hold it, it moves with the TCP; unseen, it lies where it was last seen. The
  goal is LIFT_GOAL above the first sighting, as the node sets it;
* action: the TCP's move to the next frame over MAX_STEP per axis (clipped to [-1, 1]), and
  the gripper: closed (-1) from the frame its opening starts to fall until it starts to rise;
* the episode stops where the node would stop it: the ball lifted to the goal, or
  EPISODE_STEPS; the last step is cut there as by a time limit. A lift is followed by
  HOLD_STEPS steps of the ball held still there (closed, no move): the recording's episode
  ends at the lift, the environment's go on to their last step, where success is judged;
* a move further than MAX_STEP along an axis (the pick's joint moves are faster than the
  environment's steps) is split into as many steps as it takes (split_step);
* pauses are dropped: a step with the TCP still (under IDLE_MOVE) and the gripper command
  unchanged (the pick waits for the fingers to close, and for its grasp check, with the arm
  still; in the environment the step that closes the RG2 lasts until its fingers stop). The
  step before a pause leads to the observation after it.

Frames are taken at the environment's CONTROL_RATE (10 Hz): a data set at a multiple of it is
subsampled, any other rate refused.
"""

from __future__ import annotations

from dataclasses import dataclass
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from ur_rg2_common.camera_pose import optical_rotation
from ur_rg2_common.contract import RG2_MAX_OPENING

from ur_rg2_learning import EPISODE_STEPS, PICK_ID
from ur_rg2_learning.episode import Episode, Outcome
from ur_rg2_learning.robot import CONTROL_RATE, MAX_STEP
from ur_rg2_learning.tasks import (
    BALL_RADIUS,
    BALL_SLICE,
    BALL_VELOCITY_SLICE,
    OFFSET_SLICE,
    pick_goal,
    pick_observation,
)

CODEBASE_VERSION = 'v3.0'
STATE, ENVIRONMENT = 'observation.state', 'observation.environment_state'
# The sim's default camera pose (world frame, m): ur_rg2_sim.camera.CameraConfig, graph.yaml.
CAMERA_POSITION = (1.3, -1.1, 0.95)
CAMERA_LOOK_AT = (0.3, -0.1, 0.1)
GRIPPER_CHANGE = 0.001  # m of opening per frame: the fingers are moving
OBSERVATION_KEYS = ('achieved_goal', 'desired_goal', 'observation')
# Steps of a lifted ball held still added after each episode that lifted it (as many as the
# scripted demonstrations keep): a recorded episode ends at the lift, the environment's go on.
HOLD_STEPS = 10
# Action units (of MAX_STEP): a recorded step whose moves are all below this and whose gripper
# command is the last one's is a pause of the demonstrator (the pick waiting for the fingers,
# for its grasp check): dropped, so that one state does not ask for both waiting and moving.
IDLE_MOVE = 0.02


class DatasetError(ValueError):
    """A directory that is not a usable data set; str() says why."""


@dataclass
class Dataset:
    """A data set's frames, per episode: state (n, 7), environment (n, 4), success."""

    path: Path
    fps: int
    states: list[np.ndarray]
    environments: list[np.ndarray]
    successes: list[bool]

    @property
    def frames(self) -> int:
        """The frames of all its episodes."""
        return sum(len(states) for states in self.states)


def read_dataset(directory: str | Path) -> Dataset:
    """Read a LeRobot v3.0 data set's frames (DatasetError when it is not one, or empty)."""
    import pyarrow.parquet as pq

    path = Path(directory)
    if not path.is_dir():
        raise DatasetError(f'{path}: no such directory')
    info_path = path / 'meta' / 'info.json'
    try:
        info = json.loads(info_path.read_text())
    except FileNotFoundError:
        raise DatasetError(f'{path}: not a LeRobot data set (no meta/info.json)') from None
    except (OSError, ValueError) as error:
        raise DatasetError(f'{path}: meta/info.json unreadable: {error}') from None
    if not isinstance(info, dict) or info.get('codebase_version') != CODEBASE_VERSION:
        version = info.get('codebase_version') if isinstance(info, dict) else None
        raise DatasetError(f'{path}: a LeRobot data set of codebase version {version!r}; '
                           f'this reads {CODEBASE_VERSION} (to_lerobot writes it)')
    features = info.get('features', {})
    for key, size in ((STATE, 7), (ENVIRONMENT, 4)):
        shape = features.get(key, {}).get('shape')
        if shape != [size]:
            raise DatasetError(f'{path}: no {key} of {size} values per frame (has '
                               f"{shape or 'none'}): not a data set of this robot "
                               '(to_lerobot writes one)')
    fps = info.get('fps')
    if not isinstance(fps, int) or fps <= 0 or fps % round(CONTROL_RATE):
        raise DatasetError(f'{path}: frames at {fps} fps; the Pick environment steps at '
                           f'{CONTROL_RATE:g} Hz: export at a multiple of it (to_lerobot --fps '
                           f'{CONTROL_RATE:g})')
    files = sorted((path / 'data').glob('*/*.parquet'))
    if not files:
        raise DatasetError(f'{path}: no data/*/*.parquet: no frames')
    columns = [STATE, ENVIRONMENT, 'episode_index', 'frame_index', 'next.success']
    try:
        tables = [pq.read_table(file, columns=columns) for file in files]
    except Exception as error:  # noqa: BLE001 - pyarrow raises several kinds
        raise DatasetError(f'{path}: its frames do not read ({type(error).__name__}: '
                           f'{error})') from None
    episodes = np.concatenate([t.column('episode_index').to_numpy() for t in tables])
    if not len(episodes):
        raise DatasetError(f'{path}: no episodes (no frames in its data files)')
    frame = np.concatenate([t.column('frame_index').to_numpy() for t in tables])
    success = np.concatenate([t.column('next.success').to_numpy(zero_copy_only=False)
                              for t in tables])
    state = np.concatenate([np.stack(t.column(STATE).to_pylist()) for t in tables])
    environment = np.concatenate([np.stack(t.column(ENVIRONMENT).to_pylist()) for t in tables])
    step = fps // round(CONTROL_RATE)
    dataset = Dataset(path, fps, [], [], [])
    for index in np.unique(episodes):
        rows = np.flatnonzero(episodes == index)
        rows = rows[np.argsort(frame[rows], kind='stable')]
        dataset.successes.append(bool(success[rows].any()))
        rows = rows[::step]
        dataset.states.append(state[rows].astype(np.float64))
        dataset.environments.append(environment[rows].astype(np.float64))
    return dataset


def gripper_commands(openings: np.ndarray) -> np.ndarray:
    """Return per frame whether the RG2 was commanded closed over it (True) or open.

    Closed from a frame whose next opening is smaller (the fingers closing) until one whose
    next opening is larger (opening); open at the start. NaN openings keep the last command.
    """
    closed, commands = False, np.zeros(len(openings), dtype=bool)
    for i in range(len(openings)):
        if i + 1 < len(openings):
            change = openings[i + 1] - openings[i]
            if change < -GRIPPER_CHANGE:
                closed = True
            elif change > GRIPPER_CHANGE:
                closed = False
        commands[i] = closed
    return commands


def split_step(observation: dict, following: dict,
               action: np.ndarray) -> list[tuple[dict, np.ndarray, dict]]:
    """Return a recorded step as steps the environment can take: (observation, action, next).

    A TCP that went further than MAX_STEP along an axis (the pick's joint moves reach 1 m/s,
    the environment's steps 0.5 m/s) gives as many steps as that takes, each an equal part of
    the move, the observations between on the straight line (TCP, ball, and the speeds of
    each part); the recorded action would have been clipped, and the path not followed.
    """
    start, end = observation['observation'], following['observation']
    move = (end[:3].astype(np.float64) - start[:3]) / MAX_STEP
    parts = max(1, math.ceil(float(np.max(np.abs(move))) - 1e-6))
    if parts == 1:
        return [(observation, np.append(np.clip(move, -1.0, 1.0), action[3]).astype(
            np.float32), following)]
    step = np.append(move / parts, action[3]).astype(np.float32)
    points = [observation]
    for j in range(1, parts):
        share = j / parts
        state = start + share * (end - start)
        state[3:6] = (end[:3] - start[:3]) / parts * CONTROL_RATE
        state[BALL_VELOCITY_SLICE] = (end[BALL_SLICE] - start[BALL_SLICE]) / parts * CONTROL_RATE
        state[6] = start[6]
        points.append({'observation': state.astype(np.float32),
                       'achieved_goal': state[BALL_SLICE].astype(np.float32),
                       'desired_goal': observation['desired_goal']})
    points.append(following)
    return [(points[j], step, points[j + 1]) for j in range(parts)]


def pause(actions: list[np.ndarray], i: int) -> bool:
    """Return whether recorded step ``i`` is a pause: the TCP still, the gripper unchanged."""
    action = actions[i]
    still = float(np.max(np.abs(action[:3]))) < IDLE_MOVE
    return still and (i == 0 or actions[i - 1][3] == action[3])


class Frames:
    """Turns a data set's frames into Pick steps with the environment's arm and camera pose."""

    def __init__(self, arm: Any, pedestal_height: float,
                 camera_position: tuple[float, float, float] = CAMERA_POSITION,
                 camera_look_at: tuple[float, float, float] = CAMERA_LOOK_AT) -> None:
        self.arm = arm
        self.rotation = optical_rotation(camera_position, camera_look_at)
        # Optical frame -> base_link: into the world, then down to the base on its pedestal.
        self.offset = np.asarray(camera_position, dtype=float) - (0.0, 0.0, pedestal_height)

    def ball(self, environment: np.ndarray) -> np.ndarray | None:
        """Return the ball's centre (base_link) from a frame's environment state; None: unseen."""
        if not environment[3] > 0.5 or not np.all(np.isfinite(environment[:3])):
            return None
        return self.rotation @ environment[:3] + self.offset

    @staticmethod
    def _lifted(last: dict, previous_tcp: np.ndarray, tcp: np.ndarray, opening: float,
                goal: np.ndarray) -> dict:
        """Return the observation where the node ends the episode: the ball held at the goal.

        The node returns its outcome there instead of an observation; built as it would be,
        the ball held where it was relative to the TCP at the last step.
        """
        ball = tcp + last['observation'][OFFSET_SLICE]
        ball_velocity = (ball - last['observation'][BALL_SLICE]) * CONTROL_RATE
        return pick_observation(tcp, (tcp - previous_tcp) * CONTROL_RATE, opening, ball,
                                ball_velocity, goal)

    def episode_steps(self, states: np.ndarray, environments: np.ndarray) -> dict[str, list]:
        """Return one episode's steps: observation keys, ``action``, ``next_<key>``, etc."""
        rows: dict[str, list] = {}
        balls = [self.ball(environment) for environment in environments]
        seen = [i for i, ball in enumerate(balls) if ball is not None]
        if not seen or len(states) < 2:
            return rows
        first = seen[0]  # the node starts its episode from a sighting
        openings = np.nan_to_num(states[:, 6], nan=RG2_MAX_OPENING)
        closed = gripper_commands(openings)
        tcps = [self.arm.tcp_pose(joints)[:3, 3] for joints in states[:, :6]]
        episode = Episode(True, tcps[first], states[first, :6], pick_goal(balls[first]),
                          BALL_RADIUS, math.inf)
        observations: list[dict] = []
        actions: list[np.ndarray] = []
        recorded = len(states)  # steps taken from the recording (then the hold's)
        for i in range(first, len(states)):
            episode.closed = bool(closed[i - 1]) if i > first else False
            sighting = balls[i]

            def ball(sighting=sighting) -> np.ndarray:
                if sighting is None:
                    raise ValueError('not seen')
                return sighting
            try:
                observation = episode.observe(self.arm, states[i, :6], openings[i], ball)
            except ValueError:  # lost for too long
                break
            if isinstance(observation, Outcome):
                if observation.reached and observations:  # the step that lifted it counts
                    lifted = self._lifted(observations[-1], tcps[i - 1], tcps[i], openings[i],
                                          episode.goal)
                    observations.append(lifted)
                    recorded = len(actions)
                    # Then held still there: the environment's episodes go on to their end.
                    held = self._lifted(lifted, tcps[i], tcps[i], openings[i], episode.goal)
                    observations.extend([held] * HOLD_STEPS)
                    actions.extend([np.array([0.0, 0.0, 0.0, -1.0], np.float32)] * HOLD_STEPS)
                break
            observations.append(observation)
            if i + 1 == len(states):
                break
            move = (tcps[i + 1] - tcps[i]) / MAX_STEP
            actions.append(np.append(np.clip(move, -1.0, 1.0),
                                     -1.0 if closed[i] else 1.0).astype(np.float32))
            episode.step += 1
            if episode.step >= EPISODE_STEPS[PICK_ID]:
                break
        # A step needs the observation after it: as many steps as observations but the last.
        count = min(len(actions), len(observations) - 1)
        recorded = min(count, recorded)  # the steps after it hold the lifted ball: no pauses
        kept = [i for i in range(count) if i >= recorded or not pause(actions, i)] + [count]
        steps = [step for i, following in zip(kept[:-1], kept[1:])
                 for step in split_step(observations[i], observations[following], actions[i])]
        for n, (observation, action, following) in enumerate(steps):
            last = n == len(steps) - 1
            for key in OBSERVATION_KEYS:
                rows.setdefault(key, []).append(observation[key])
                rows.setdefault(f'next_{key}', []).append(following[key])
            rows.setdefault('action', []).append(action)
            rows.setdefault('done', []).append(last)
            rows.setdefault('truncated', []).append(last)
        return rows


def demonstrations(dataset: Dataset, env: Any,
                   camera_position: tuple[float, float, float] = CAMERA_POSITION,
                   camera_look_at: tuple[float, float, float] = CAMERA_LOOK_AT
                   ) -> dict[str, np.ndarray]:
    """Return the data set's steps in the form of demonstrations.scripted_demonstrations.

    ``env`` is a Pick environment (its arm, pedestal and reward); each episode's steps come
    one after the other, the last of each marked done (cut as by a time limit). DatasetError
    when no episode gives a step (the ball never seen, episodes of one frame).
    """
    base = env.unwrapped
    frames = Frames(base.arm, base.world.pedestal_height, camera_position, camera_look_at)
    rows: dict[str, list] = {}
    for states, environments in zip(dataset.states, dataset.environments):
        steps = frames.episode_steps(states, environments)
        for key, values in steps.items():
            rows.setdefault(key, []).extend(values)
    if not rows:
        raise DatasetError(f'{dataset.path}: none of its {len(dataset.states)} episodes gives '
                           'a step (vision never saw the ball, or one frame each)')
    result = {key: np.array(values) for key, values in rows.items()}
    result['reward'] = np.asarray(base.compute_reward(
        result['next_achieved_goal'], result['next_desired_goal'], None), dtype=np.float32)
    return result


def dataset_demonstrations(directory: str | Path, env: Any,
                           camera_position: tuple[float, ...] = CAMERA_POSITION,
                           camera_look_at: tuple[float, ...] = CAMERA_LOOK_AT
                           ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Return the steps of the data set in ``directory`` and what policy.json says of it."""
    dataset = read_dataset(directory)
    steps = demonstrations(dataset, env, tuple(camera_position), tuple(camera_look_at))
    meta = {'dataset': {
        'path': str(directory), 'fps': dataset.fps, 'episodes': len(dataset.states),
        'successes': sum(dataset.successes), 'frames': dataset.frames,
        'episodes_used': int(np.sum(steps['done'])), 'steps': len(steps['action']),
        'camera_position': list(camera_position), 'camera_look_at': list(camera_look_at)}}
    return steps, meta
