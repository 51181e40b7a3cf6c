"""A scripted Pick policy: over the ball, down, close, lift. The demonstrations for training.

It reads only the observation (as a learned policy does): the TCP, the gripper's opening and
the ball, all in ``base_link``. ``noise`` adds Gaussian exploration to its moves, so that
demonstrations show more than one path.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ur_rg2_learning.robot import MAX_STEP
from ur_rg2_learning.tasks import GRASP_HEIGHT

# The grasp (GRASP_HEIGHT over the ball's centre) is approached from APPROACH_HEIGHT once
# over the ball.
APPROACH_HEIGHT = 0.08  # m
OVER = 0.005  # m: horizontally this near the ball the TCP is over it
AT_GRASP = 0.005  # m: vertically this near the grasp height it closes
# With the ball at the TCP, closed fingers between these openings hold it (the 6 cm ball
# stops them at 58 mm; a step that closes the RG2 ends when its fingers stop).
HOLDING_OPENING = (0.002, 0.07)  # m
HELD_DISTANCE = 0.03  # m, ball centre to TCP


def pick_action(observation: Mapping[str, np.ndarray], rng: np.random.Generator | None = None,
                noise: float = 0.0) -> np.ndarray:
    """Return the scripted action for a ``UrRg2Pick-v0`` observation."""
    o = np.asarray(observation['observation'], dtype=np.float64)
    tcp, opening, ball = o[0:3], o[6], o[7:10]
    goal = np.asarray(observation['desired_goal'], dtype=np.float64)
    at_tcp = np.linalg.norm(ball - tcp) < HELD_DISTANCE
    if at_tcp and HOLDING_OPENING[0] < opening < HOLDING_OPENING[1]:
        move, grip = goal - tcp, -1.0  # held: to the goal above
    else:
        grasp = ball + (0.0, 0.0, GRASP_HEIGHT)
        over = np.linalg.norm(grasp[:2] - tcp[:2]) < OVER
        if over and abs(tcp[2] - grasp[2]) < AT_GRASP:
            move, grip = np.zeros(3), -1.0  # close on it
        else:
            height = 0.0 if over else APPROACH_HEIGHT
            move, grip = grasp + (0.0, 0.0, height) - tcp, 1.0
    action = move / MAX_STEP
    if noise > 0 and rng is not None:
        action = action + rng.normal(0.0, noise, 3)
    return np.clip(np.append(action, grip), -1.0, 1.0).astype(np.float32)
