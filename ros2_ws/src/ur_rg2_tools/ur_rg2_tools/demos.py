"""The ``demos`` command's episode loop, without ROS: options, the loop, the progress line.

Each episode places the ball at a random floor position the arm reaches and the camera sees
(:func:`ur_rg2_vision.placement.plan_placement`, the ``dataset`` command's placements), sends
the arm home with the gripper open, waits for vision to see the ball, runs the pick (which
marks its own episode on ``episode``), then drops the ball and goes home. The ROS side
(:mod:`ur_rg2_tools.demos_node`) is the driver: parameters set, services and the pick action
called, sightings counted, and the recorder run beside it.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass, field
import os
import time
from typing import Protocol

from ur_rg2_vision.placement import REACH, Camera, PlacementError, plan_placement

PLACEMENT_TRIES = 5  # placements drawn per episode before the ball is taken as never seen
# What a LeRobot data set is made of (ur_rg2_tools.recording_frames), and the camera's info.
TOPICS = ('joint_states', 'camera/color/image_raw', 'camera/color/camera_info',
          'ball/position', 'episode')


class DemosError(Exception):
    """The graph is missing or does not do what is asked; the message says what and why."""


class StopNow(Exception):  # noqa: N818 - a stop, not an error
    """A second Ctrl-C (or SIGTERM): the episode under way is given up."""


class Driver(Protocol):
    """What the loop asks of the graph (ur_rg2_tools.demos_node.GraphDriver)."""

    def place_ball(self, position: tuple[float, float, float]) -> None:
        """Move the ball there (the sim's ``ball_position``)."""

    def home(self) -> None:
        """Open the gripper and send the arm home; return once it is there."""

    def see_ball(self) -> bool:
        """Return whether vision sees the ball (fresh ``ball/position``s) within its time."""

    def pick(self) -> tuple[bool, str]:
        """Run the pick (``pick_ball`` action); return (success, its message)."""

    def drop(self) -> None:
        """Open the gripper (``gripper/open``)."""


def parse_args(argv: list[str]) -> argparse.Namespace:
    """Parse the command line (without ROS arguments)."""
    parser = argparse.ArgumentParser(
        prog='demos', description='Record N pick episodes of the running graph, the ball at a '
        'random reachable place in view each time, to an MCAP file that to_lerobot exports.')
    parser.add_argument('-o', '--output', required=True, metavar='FILE',
                        help='the MCAP file to write (never overwritten)')
    parser.add_argument('-n', '--episodes', type=int, required=True, metavar='N',
                        help='episodes to record')
    parser.add_argument('--seed', type=int, default=0,
                        help='seed of the ball placements: one seed, the same placements '
                        '(default: 0)')
    parser.add_argument('--timeout-s', type=float, default=60.0, metavar='T',
                        help='seconds the graph may take to answer (to appear, to see the ball, '
                        'to go home) and a pick may take (default: 60)')
    parser.add_argument('--all', action='store_true',
                        help='record every topic (as record --all), not only what to_lerobot '
                        f'reads ({", ".join(TOPICS)})')
    return parser.parse_args(argv)


def check_options(options: argparse.Namespace) -> None:
    """Raise DemosError for options that cannot run: N < 1, an existing output, T <= 0."""
    if options.episodes < 1:
        raise DemosError(f'--episodes must be at least 1, not {options.episodes}')
    if options.timeout_s <= 0:
        raise DemosError(f'--timeout-s must be positive, not {options.timeout_s:g}')
    if os.path.lexists(options.output):
        raise DemosError(f'{options.output} exists: give a new file (it is never overwritten)')
    parent = os.path.dirname(os.path.abspath(options.output))
    if not os.path.isdir(parent):
        raise DemosError(f'no directory {parent} for {options.output}')


@dataclass
class Tally:
    """Episodes done so far and their pace, for the progress line."""

    total: int
    started: float = field(default_factory=time.monotonic)
    done: int = 0
    successes: int = 0
    unseen: int = 0  # episodes with no pick: vision never saw the ball

    def add(self, success: bool) -> None:
        """Count one episode."""
        self.done += 1
        self.successes += success

    def line(self, now: float | None = None) -> str:
        """Return the progress line: episode i/N, successes, time per episode and ETA."""
        elapsed = (time.monotonic() if now is None else now) - self.started
        plural = '' if self.successes == 1 else 'es'
        line = f'episode {self.done}/{self.total}: {self.successes} success{plural}'
        if self.done:
            per = elapsed / self.done
            line += (f' ({100 * self.successes / self.done:.0f}%), {per:.1f} s per episode, '
                     f'ETA {format_duration(per * (self.total - self.done))}')
        if self.unseen:
            line += f', {self.unseen} not seen'
        return line


    def summary(self, now: float | None = None) -> str:
        """Return the closing line: episodes done of N, successes, time taken."""
        elapsed = (time.monotonic() if now is None else now) - self.started
        line = (f'{self.done} of {self.total} episodes done, {self.successes} '
                f'success{"" if self.successes == 1 else "es"}')
        if self.unseen:
            line += f', {self.unseen} not seen'
        return f'{line}, in {format_duration(elapsed)}'


def format_duration(seconds: float) -> str:
    """Return seconds as '1 h 02 min', '3 min 05 s' or '12 s'."""
    seconds = round(seconds)
    if seconds >= 3600:
        return f'{seconds // 3600} h {seconds % 3600 // 60:02d} min'
    if seconds >= 60:
        return f'{seconds // 60} min {seconds % 60:02d} s'
    return f'{seconds} s'


@dataclass(frozen=True)
class Scene:
    """What placements need of the sim: its camera, the ball's radius, the robot model."""

    camera: Camera
    radius: float
    robot_model: str

    def placement(self, seed: int, episode: int, attempt: int) -> tuple[float, float, float]:
        """Return where episode ``episode``'s ball goes (``attempt`` > 0: drawn again)."""
        reach = REACH.get(self.robot_model, REACH['ur3'])
        try:
            placement = plan_placement(seed, episode, attempt, self.camera, self.radius, reach,
                                       out_of_view_fraction=0.0, jitter_camera=False,
                                       jitter_color=False)
        except PlacementError as error:
            raise DemosError(str(error)) from None
        return tuple(float(v) for v in placement.ball)


def run_episodes(driver: Driver, scene: Scene, options: argparse.Namespace,
                 stop_requested: Callable[[], bool], say: Callable[[str], None],
                 tally: Tally | None = None) -> Tally:
    """Run the episodes until N are done or a stop is asked; return the tally (``tally``).

    ``stop_requested`` is asked between episodes (a first Ctrl-C); the driver raises StopNow
    in the middle of one (a second). An episode whose ball vision does not see after
    PLACEMENT_TRIES placements counts as not seen and publishes no marker.
    """
    tally = Tally(options.episodes) if tally is None else tally
    tally.started = time.monotonic()  # the rate is the episodes', not the start-up's
    say(tally.line())
    for episode in range(options.episodes):
        if stop_requested():
            break
        driver.drop()
        driver.home()
        for attempt in range(PLACEMENT_TRIES):
            ball = scene.placement(options.seed, episode, attempt)
            driver.place_ball(ball)
            if driver.see_ball():
                break
            say(f'episode {episode + 1}: vision did not see the ball at '
                f'({ball[0]:.3f}, {ball[1]:.3f}) m; placing it again')
        else:
            tally.unseen += 1
            say(f'episode {episode + 1}: no pick, the ball was not seen in {PLACEMENT_TRIES} '
                'placements')
            continue
        success, message = driver.pick()
        tally.add(success)
        say(f'episode {episode + 1}: {"success" if success else "failure"}: {message}')
        say(tally.line())
    driver.drop()
    driver.home()
    return tally
