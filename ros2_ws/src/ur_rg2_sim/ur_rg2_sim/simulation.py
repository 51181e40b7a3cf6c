"""The simulation thread: steps the world, keeps simulation time, paces it, schedules outputs.

Plain Python, no ROS: outputs go to callbacks. pybullet is not thread-safe, so every access to
the world from another thread goes through :meth:`SimulationLoop.call`, which runs the function
on this thread between two physics steps and returns a ``concurrent.futures.Future``.
"""

from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass
import queue
import threading
import time
from typing import Optional, Protocol

from ur_rg2_sim.camera import Camera, Frame
from ur_rg2_sim.render_thread import RenderThread
from ur_rg2_sim.world import SimWorld

NS = 1_000_000_000
# The simulation may fall this far behind the wall clock (a slow render, a loaded machine)
# before it stops trying to catch up, rather than rushing through a burst of steps.
_MAX_LAG = 0.25  # s
# /clock is published at this rate of simulation time at least (the contract's minimum).
CLOCK_RATE = 100.0


class SimulationUnavailableError(RuntimeError):
    """The simulation thread gave no answer: it stopped, or did not answer in time."""


def answer(future: Future, timeout: float):
    """Return the result of a :meth:`SimulationLoop.call`; raise SimulationUnavailableError."""
    try:
        return future.result(timeout=timeout)
    except FutureTimeout:
        raise SimulationUnavailableError('the simulation did not answer in time') from None
    except RuntimeError as error:  # the loop fails pending calls so when it stops
        raise SimulationUnavailableError(str(error)) from None


class Outputs(Protocol):
    """Where the loop sends what it produces; called on the simulation thread."""

    def clock(self, stamp_ns: int) -> None:
        """Publish the simulation time."""

    def joint_states(self, stamp_ns: int, world: SimWorld) -> None:
        """Publish the joint states of ``world`` now (sampled only if anyone listens)."""

    def frame(self, stamp_ns: int, camera: Camera, frame: Frame) -> None:
        """Publish one RGB-D frame of ``camera`` (on the camera's thread with OpenGL)."""

    def frame_dropped(self, stamp_ns: int, dropped: int) -> None:
        """Say that the frame due at ``stamp_ns`` was dropped: the last was still drawn."""


@dataclass
class Schedule:
    """Output rates (Hz of simulation time) and pacing; 0 turns an output or pacing off."""

    joint_state_rate: float = 100.0
    camera_rate: float = 30.0
    real_time_factor: float = 1.0


@dataclass
class _Waiter:
    settled: Callable[[SimWorld], bool]
    deadline_ns: int
    hold_ns: int
    future: Future
    since_ns: Optional[int] = None


class SimulationLoop:
    """Runs ``world`` on its own thread until :meth:`stop`."""

    def __init__(self, world: SimWorld, outputs: Outputs, schedule: Schedule,
                 camera: Optional[Camera] = None) -> None:
        self.world = world
        self.outputs = outputs
        self.schedule = schedule
        self.camera = camera
        self.step_ns = round(world.dt * NS)
        self.sim_time_ns = 0
        self.started_at: Optional[float] = None  # time.monotonic() when the thread started
        self.ended_at: Optional[float] = None  # and when it ended
        self.error: Optional[BaseException] = None
        # Called with (world, sim_time_ns) before every physics step (the controllers).
        self.step_hooks: list[Callable[[SimWorld, int], None]] = []
        self._calls: queue.SimpleQueue = queue.SimpleQueue()
        self._waiters: list[_Waiter] = []
        self._stop = threading.Event()
        self._wake = threading.Event()  # set by call(): run it now, even while pacing
        self._finished = threading.Event()
        self._thread = threading.Thread(target=self._run, name='simulation', daemon=True)
        self._next_clock = self._next_joint_states = self._next_frame = 0
        self._next_output = 0  # the earliest of the three that is on: steps before it skip
        self._pace_origin: Optional[tuple[float, int]] = None
        self._render_thread = RenderThread(outputs.frame)
        self.frames_dropped = 0
        self._frames_on_loop = 0  # drawn on this thread (TinyRenderer)

    # -- any thread ---------------------------------------------------------------------------

    def start(self) -> None:
        """Start the simulation thread (once the camera has drawn its first frame)."""
        if self.camera is not None and self.camera.draws_off_thread:
            self._render_thread.warm_up(self.camera, self.camera.snapshot())
        self._thread.start()

    def stop(self, timeout: float = 10.0) -> bool:
        """Stop the simulation thread; return whether it ended within ``timeout`` seconds.

        It ends after the step it is in: a render on a loaded machine can take a good part of
        a second, so the default leaves room for several.
        """
        self._stop.set()
        self._wake.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout)
        self._render_thread.stop(timeout)
        return not self._thread.is_alive()

    def summary(self) -> str:
        """Return how much simulation time ran, in how much wall time, and at what speed.

        The wall time is the thread's run, up to now or to its end (not the node's teardown).
        """
        end = self.ended_at if self.ended_at is not None else time.monotonic()
        wall = end - self.started_at if self.started_at is not None else 0.0
        sim = self.sim_time_ns / NS
        steps = self.sim_time_ns // self.step_ns
        if wall <= 0:
            return 'the simulation did not run'
        frames = self._render_thread.drawn + self._frames_on_loop
        camera = (f'; camera: {frames} frames drawn, {self.frames_dropped} dropped'
                  if frames or self.frames_dropped else '')
        return (f'simulated {sim:.1f} s in {wall:.1f} s ({sim / wall:.2f}x real time, '
                f'{steps / wall:,.0f} physics steps/s){camera}')

    def call(self, function: Callable[[SimWorld], object]) -> Future:
        """Run ``function(world)`` on the simulation thread before the next step."""
        future: Future = Future()
        self._calls.put((function, future))
        self._wake.set()
        if self._finished.is_set():
            self._fail_pending(RuntimeError('the simulation is not running'))
        return future

    def wait_until(self, action: Callable[[SimWorld], object],
                   settled: Callable[[SimWorld], bool], timeout_s: float,
                   hold_s: float = 0.0) -> Future:
        """Run ``action``, then resolve True once ``settled`` has held for ``hold_s``.

        Times are simulation time; the future resolves False after ``timeout_s``.
        """
        result: Future = Future()

        def start(world: SimWorld) -> None:
            action(world)
            self._waiters.append(_Waiter(settled, self.sim_time_ns + round(timeout_s * NS),
                                         round(hold_s * NS), result))

        started = self.call(start)
        started.add_done_callback(
            lambda f: f.exception() is not None and result.set_exception(f.exception()))
        return result

    def reschedule(self, schedule: Schedule, camera: Optional[Camera]) -> Future:
        """Change rates, pacing or camera from the next step on."""
        def apply(world: SimWorld) -> None:
            self.schedule = schedule
            self.camera = camera
            self._next_joint_states = self._next_frame = self.sim_time_ns
            self._next_output = min(self._next_output, self.sim_time_ns)
            self._pace_origin = None
        return self.call(apply)

    # -- simulation thread --------------------------------------------------------------------

    def _run(self) -> None:
        self.started_at = time.monotonic()
        try:
            # Looked up once, and each step's checks inline: thousands of steps/s, where a
            # method call costs a few per cent of a physics step.
            world, hooks, calls, stopped = self.world, self.step_hooks, self._calls, self._stop
            while not stopped.is_set():
                if not calls.empty():
                    self._run_calls()
                for hook in hooks:
                    hook(world, self.sim_time_ns)
                world.step()
                self.sim_time_ns += self.step_ns
                if self._waiters:
                    self._check_waiters()
                if self.sim_time_ns >= self._next_output:
                    self._publish_due()
                if self.schedule.real_time_factor > 0:
                    self._pace()
        except BaseException as error:  # noqa: B036 - reported to the node, which exits
            self.error = error
        finally:
            self.ended_at = time.monotonic()
            self._finished.set()
            self._fail_pending(RuntimeError('the simulation stopped'))

    def _run_calls(self) -> None:
        while not self._calls.empty():
            function, future = self._calls.get_nowait()
            if future.set_running_or_notify_cancel():
                try:
                    future.set_result(function(self.world))
                except Exception as error:  # noqa: BLE001 - handed to the caller
                    future.set_exception(error)

    def _check_waiters(self) -> None:
        now = self.sim_time_ns
        for waiter in list(self._waiters):
            if waiter.settled(self.world):
                waiter.since_ns = now if waiter.since_ns is None else waiter.since_ns
                done = now - waiter.since_ns >= waiter.hold_ns
                result = True
            else:
                waiter.since_ns = None
                done = now >= waiter.deadline_ns
                result = False
            if done:
                self._waiters.remove(waiter)
                waiter.future.set_result(result)

    def _publish_due(self) -> None:
        now = self.sim_time_ns
        schedule = self.schedule
        if now >= self._next_clock:
            self.outputs.clock(now)
            self._next_clock = _next_due(self._next_clock, now, CLOCK_RATE)
        due = [self._next_clock]
        if schedule.joint_state_rate > 0:
            if now >= self._next_joint_states:
                self.outputs.joint_states(now, self.world)
                self._next_joint_states = _next_due(self._next_joint_states, now,
                                                    schedule.joint_state_rate)
            due.append(self._next_joint_states)
        if self.camera is not None and schedule.camera_rate > 0:
            if now >= self._next_frame:
                self._capture(now, self.camera)
                self._next_frame = _next_due(self._next_frame, now, schedule.camera_rate)
            due.append(self._next_frame)
        self._next_output = min(due)

    def _capture(self, now: int, camera: Camera) -> None:
        """Draw a frame: on the camera thread with OpenGL, else (TinyRenderer) here."""
        if not camera.draws_off_thread:
            self.outputs.frame(now, camera, camera.render())
            self._frames_on_loop += 1
            return
        renderer = self._render_thread
        if renderer.error is not None:
            raise RuntimeError(f'the camera failed: {renderer.error!r}') from renderer.error
        if self.schedule.real_time_factor <= 0:
            renderer.wait_idle()  # unpaced, there is no wall clock to keep up with
        if not renderer.submit(now, camera, camera.snapshot()):
            self.frames_dropped += 1
            self.outputs.frame_dropped(now, self.frames_dropped)

    def _pace(self) -> None:
        rtf = self.schedule.real_time_factor
        wall = time.monotonic()
        if self._pace_origin is None:
            self._pace_origin = (wall, self.sim_time_ns)
        origin_wall, origin_sim = self._pace_origin
        due = origin_wall + (self.sim_time_ns - origin_sim) / NS / rtf
        if due - wall < -_MAX_LAG:
            self._pace_origin = (wall, self.sim_time_ns)
            return
        # Commands arriving while the loop waits for the wall clock take effect at once:
        # a jog then moves the arm in the very next step.
        while (remaining := due - time.monotonic()) > 0 and not self._stop.is_set():
            if self._wake.wait(remaining):
                self._wake.clear()
                self._run_calls()
                if self._pace_origin is None:  # rescheduled: pace from here afresh
                    return

    def _fail_pending(self, error: Exception) -> None:
        while not self._calls.empty():
            _, future = self._calls.get_nowait()
            if not future.done():
                future.set_exception(error)
        while self._waiters:
            waiter = self._waiters.pop()
            if not waiter.future.done():
                waiter.future.set_exception(error)


def _next_due(previous_due: int, now: int, rate: float) -> int:
    """Return the next due time after ``now`` on a fixed grid, skipping missed slots."""
    period = max(1, round(NS / rate))
    due = previous_due + period
    return due if due > now else now + period
