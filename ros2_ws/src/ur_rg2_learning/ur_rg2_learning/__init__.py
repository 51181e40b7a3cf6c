"""Gymnasium environments on the sim's world, a DDPG baseline and the ``policy`` node.

Importing the package registers ``UrRg2Reach-v0`` and ``UrRg2Pick-v0``.
"""

from gymnasium.envs.registration import register

REACH_ID = 'UrRg2Reach-v0'
PICK_ID = 'UrRg2Pick-v0'
# Steps of 0.1 s: Reach 5 s (the TCP crosses the sampled region in under 2 s), Pick 10 s.
EPISODE_STEPS = {REACH_ID: 50, PICK_ID: 100}

register(id=REACH_ID, entry_point='ur_rg2_learning.envs:ReachEnv',
         max_episode_steps=EPISODE_STEPS[REACH_ID])
register(id=PICK_ID, entry_point='ur_rg2_learning.envs:PickEnv',
         max_episode_steps=EPISODE_STEPS[PICK_ID])
