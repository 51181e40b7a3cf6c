"""The controllers' halves that run on the simulation thread. Plain Python, no ROS.

:class:`ArmDriver` samples the running trajectory before every physics step and sets the arm's
position targets; :class:`GripperDriver` watches the fingers until they stop. Each goal is a
*run* whose ``done`` future (a ``concurrent.futures.Future``) resolves with how it
:class:`Ended`, and whose latest state other threads may read at any time (for feedback).
Every method here must be called on the simulation thread.
"""

from concurrent.futures import Future, InvalidStateError
from dataclasses import dataclass, field
from typing import Optional

import numpy as np
from ur_rg2_common.contract import ARM_JOINTS

from ur_rg2_sim.execution import Execution, Sample
from ur_rg2_sim.simulation import NS
from ur_rg2_sim.trajectory import (
    INVALID_GOAL,
    SUCCESSFUL,
    Goal,
    limits_of,
    plan,
)
from ur_rg2_sim.world import SimWorld

# The fingers count as stopped once they have not moved for this long (as the services do).
GRIPPER_SETTLE_TIME = 0.1  # s
# The fingers reached the commanded opening when they stop this close to it.
GRIPPER_GOAL_TOLERANCE = 0.002  # m
# A gripper goal whose fingers have not stopped after this long is aborted.
GRIPPER_TIMEOUT = 5.0  # s of simulation time


@dataclass(frozen=True)
class Ended:
    """How a goal ended: ``status`` is 'succeeded', 'aborted' or 'canceled'."""

    status: str
    code: int
    message: str
    logged: bool = False  # the reason has been logged as a warning already


def _finish(done: Future, ended: Ended) -> None:
    try:
        done.set_result(ended)
    except InvalidStateError:
        pass  # already ended (e.g. the simulation stopped first)


@dataclass
class ArmRun:
    """One follow_joint_trajectory goal being executed."""

    execution: Execution
    done: Future = field(default_factory=Future)

    @property
    def sample(self) -> Optional[Sample]:
        """Return the latest desired and actual state (None before the first step)."""
        return self.execution.last


class ArmDriver:
    """Runs one trajectory at a time on the arm."""

    def __init__(self) -> None:
        self.active: Optional[ArmRun] = None

    def start(self, world: SimWorld, now_ns: int, goal: Goal,
              start_ns: Optional[int]) -> ArmRun:
        """Plan ``goal`` from the arm's current state and run it, preempting the running one.

        ``start_ns`` is the goal's start in simulation time (None: now). Raises
        TrajectoryError when the goal cannot be planned; the running goal then goes on.
        """
        positions, velocities = _arm_state(world, goal.joints)
        velocity, lower, upper = limits_of(goal.joints, world.limits)
        spline = plan(goal, now_ns / NS, None if start_ns is None else start_ns / NS,
                      positions, velocities, velocity, (lower, upper))
        self.preempt('preempted by a new trajectory goal')
        self.active = ArmRun(Execution(goal, spline))
        return self.active

    def preempt(self, reason: str, code: int = INVALID_GOAL, logged: bool = False) -> None:
        """End the running goal, aborted with ``reason``; the arm keeps its current targets.

        ``code`` is the result's error code: INVALID_GOAL for a goal another command
        replaced (as ros2_control reports it), PATH_TOLERANCE_VIOLATED for one whose path is
        blocked; ``logged`` says that the reason has been logged as a warning already.
        """
        if self.active is not None:
            _finish(self.active.done, Ended('aborted', code, reason, logged))
            self.active = None

    def cancel(self, world: SimWorld, run: ArmRun) -> None:
        """End ``run`` as canceled, holding its joints where they are."""
        if self.active is run:
            self.active = None
            positions, _ = _arm_state(world, run.execution.goal.joints)
            world.set_arm_targets(dict(zip(run.execution.goal.joints, positions)))
        _finish(run.done, Ended('canceled', SUCCESSFUL,
                                'canceled: the arm holds where it was'))

    def step(self, world: SimWorld, now_ns: int) -> None:
        """Judge the state at ``now_ns`` and set the targets for the end of the next step."""
        run = self.active
        if run is None:
            return
        joints = run.execution.goal.joints
        now = now_ns / NS
        positions, velocities = _arm_state(world, joints)
        outcome = run.execution.update(now, positions, velocities)
        if outcome is None or outcome.code == SUCCESSFUL:
            target, target_velocity, _ = run.execution.desired(now + world.dt)
            world.set_arm_targets(dict(zip(joints, target.tolist())),
                                  dict(zip(joints, target_velocity.tolist())))
        else:  # tolerance violated: hold, as ros2_control does
            world.set_arm_targets(dict(zip(joints, positions.tolist())))
        if outcome is not None:
            self.active = None
            _finish(run.done, Ended('succeeded' if outcome.code == SUCCESSFUL else 'aborted',
                                    outcome.code, outcome.message))

    def close(self, reason: str) -> None:
        """End every goal (the simulation is stopping)."""
        self.preempt(reason)


def _arm_state(world: SimWorld, joints: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    sample = world.joint_states()
    index = [ARM_JOINTS.index(name) for name in joints]
    return (np.array([sample.positions[i] for i in index]),
            np.array([sample.velocities[i] for i in index]))


@dataclass(frozen=True)
class GripperState:
    """The fingers as a GripperCommand result or feedback reports them."""

    position: float  # m between the pads
    effort: float  # N
    stalled: bool
    reached_goal: bool


@dataclass
class GripperRun:
    """One gripper_cmd goal being executed."""

    target: float
    force: float
    deadline_ns: int
    state: Optional[GripperState] = None
    stopped_since_ns: Optional[int] = None
    done: Future = field(default_factory=Future)


class GripperDriver:
    """Drives the fingers for one GripperCommand goal at a time."""

    def __init__(self) -> None:
        self.active: Optional[GripperRun] = None

    def start(self, world: SimWorld, now_ns: int, position: float,
              max_effort: float) -> GripperRun:
        """Move the fingers to ``position`` (m) with ``max_effort`` (N, <= 0: the maximum)."""
        self.preempt('preempted by a new gripper goal')
        target, force = (world.command_gripper(position, max_effort) if max_effort > 0
                         else world.command_gripper(position))
        self.active = GripperRun(target, force, now_ns + round(GRIPPER_TIMEOUT * NS))
        self.active.state = self._state(world, self.active, stopped=False)
        return self.active

    def preempt(self, reason: str) -> None:
        """End the running goal, aborted with ``reason``."""
        if self.active is not None:
            _finish(self.active.done, Ended('aborted', 0, reason))
            self.active = None

    def cancel(self, world: SimWorld, run: GripperRun) -> None:
        """End ``run`` as canceled, the fingers held where they are."""
        if self.active is run:
            self.active = None
            world.command_gripper(world.gripper_opening(), run.force)
        _finish(run.done, Ended('canceled', 0, 'canceled: the fingers hold where they were'))

    def step(self, world: SimWorld, now_ns: int) -> None:
        """Update the running goal's state; end it once the fingers have settled."""
        run = self.active
        if run is None:
            return
        if (world.gripper_target, world.gripper_force) != (run.target, run.force):
            self.preempt('preempted by a gripper/open or gripper/close call')
            return
        stopped = world.gripper_stopped()
        if not stopped:
            run.stopped_since_ns = None
        elif run.stopped_since_ns is None:
            run.stopped_since_ns = now_ns
        settled = stopped and now_ns - run.stopped_since_ns >= GRIPPER_SETTLE_TIME * NS
        run.state = state = self._state(world, run, settled)
        if settled:
            self.active = None
            what = ('reached' if state.reached_goal else
                    f'stalled on an object {abs(state.position - run.target) * 1000:.1f} mm '
                    'before')
            _finish(run.done, Ended('succeeded', 0, f'{what} the target '
                                    f'{run.target * 1000:.1f} mm: {state.position * 1000:.1f} '
                                    f'mm at {state.effort:.1f} N'))
        elif now_ns >= run.deadline_ns:
            self.active = None
            _finish(run.done, Ended('aborted', 0, 'the fingers did not stop within '
                                    f'{GRIPPER_TIMEOUT:g} s of simulation time'))

    @staticmethod
    def _state(world: SimWorld, run: GripperRun, stopped: bool) -> GripperState:
        opening = world.gripper_opening()
        reached = abs(opening - run.target) <= GRIPPER_GOAL_TOLERANCE
        return GripperState(opening, world.gripper_effort(), stopped and not reached, reached)

    def close(self, reason: str) -> None:
        """End every goal (the simulation is stopping)."""
        self.preempt(reason)
