"""The camera's two renderers: OpenGL (EGL) and pybullet's TinyRenderer draw the same camera.

And the simulation loop draws OpenGL frames off its thread: a stalled render drops camera
frames, never physics steps or joint states.
"""

import threading

from conftest import wait_for
import numpy as np
import pytest
from ur_rg2_common.contract import ARM_JOINTS
from ur_rg2_sim.camera import Camera, CameraConfig, RendererError, choose_renderer
from ur_rg2_sim.render_thread import DropWatch
from ur_rg2_sim.simulation import NS, Schedule, SimulationLoop
from ur_rg2_sim.world import SimWorld, WorldConfig

EGL = choose_renderer('auto').name == 'egl'
needs_egl = pytest.mark.skipif(not EGL, reason='no EGL context loads on this machine')

SCENES = {
    'default camera, arm bent over a box and a disc': (
        CameraConfig(), [0.3, -1.0, 1.2, -1.5, -1.2, 0.4]),
    'near camera, gripper over the ball': (
        CameraConfig(position=(0.95, -0.75, 0.45), look_at=(0.45, -0.35, 0.03)),
        [-0.6, -0.7, 1.6, -2.4, -1.57, 0.0]),
    'far camera from the other side, other light': (
        CameraConfig(position=(-1.2, 1.5, 1.4), look_at=(0.3, 0.0, 0.2),
                     light_direction=(-0.5, 0.3, 0.8)),
        [1.0, -1.4, 0.8, -0.4, 0.6, 1.0]),
}


@pytest.fixture(scope='module')
def scene_world():
    world = SimWorld(WorldConfig(ball_position=(0.45, -0.3, 0.03)))
    world.add_box((0.5, 0.3, 0.05), (0.05, 0.03, 0.05), (0.2, 0.8, 0.2, 1))
    world.add_disc((0.6, -0.1, 0.01), 0.05, 0.02, (0.9, 0.9, 0.1, 1))
    world.add_sphere((0.3, 0.35, 0.04), 0.04, (0.9, 0.9, 0.9, 1))
    yield world
    world.close()


@needs_egl
@pytest.mark.parametrize('scene', SCENES)
def test_both_renderers_see_the_same_geometry_and_colours(scene_world, scene):
    config, joints = SCENES[scene]
    scene_world.set_arm_positions(dict(zip(ARM_JOINTS, joints)))
    gl, tiny = Camera(scene_world, config, 'egl'), Camera(scene_world, config, 'tiny')
    assert gl.renderer.name == 'egl' and tiny.renderer.name == 'tiny'
    assert np.array_equal(gl.k, tiny.k)
    try:
        ours, theirs = gl.render(), tiny.render()
    finally:
        gl.close()
    assert ours.rgb.shape == theirs.rgb.shape == (config.height, config.width, 3)
    assert ours.depth.dtype == theirs.depth.dtype == np.float32
    both = np.isfinite(ours.depth) & np.isfinite(theirs.depth)
    assert (np.isfinite(ours.depth) != np.isfinite(theirs.depth)).mean() < 0.001
    within = np.abs(ours.depth[both] - theirs.depth[both]) < 0.001
    assert within.mean() >= 0.99, f'depth within 1 mm on {within.mean():.4f} of pixels'
    difference = np.abs(ours.rgb.astype(int) - theirs.rgb.astype(int)).max(axis=-1)
    assert np.mean(difference <= 2) >= 0.98
    assert difference.mean() < 1.5


@needs_egl
def test_repainted_and_added_bodies_show_in_the_next_frame(scene_world):
    camera = Camera(scene_world, CameraConfig(), 'egl')
    try:
        u, v = (round(c) for c in camera.project(scene_world.body_position(scene_world.ball)))
        scene_world.set_ball_color((0.0, 0.0, 1.0, 1.0))
        blue = camera.render().rgb[v, u]
        scene_world.set_ball_color((1.0, 0.0, 0.0, 1.0))
        red = camera.render().rgb[v, u]
        assert blue[2] > 150 and blue[0] < 30 and red[0] > 150 and red[2] < 30
        before = camera.render().depth[v, u]
        # In the line of sight, between the camera and the ball.
        ball, eye = np.asarray(scene_world.body_position(scene_world.ball)), np.asarray(
            CameraConfig().position)
        box = scene_world.add_box(ball + 0.3 * (eye - ball), (0.03, 0.03, 0.03), (0, 1, 0, 1),
                                  mass=0)
        assert camera.render().depth[v, u] < before - 0.05
        scene_world.remove_bodies([box])
    finally:
        camera.close()


@needs_egl
def test_a_frame_keeps_nothing_of_the_frames_before(scene_world):
    """The OpenGL camera redraws where shapes were and are: what left shows the floor again."""
    config, joints = SCENES['default camera, arm bent over a box and a disc']
    camera = Camera(scene_world, config, 'egl')
    try:
        scene_world.set_arm_positions(dict(zip(ARM_JOINTS, joints)))
        box = scene_world.add_box((0.2, -0.7, 0.1), (0.06, 0.06, 0.06), (1, 0, 1, 1), mass=0)
        before = camera.render()
        scene_world.remove_bodies([box])
        # The arm swung to the other side, where the last frame showed the floor.
        scene_world.set_arm_positions(dict(zip(ARM_JOINTS, [1.4, -1.2, 1.0, -0.6, 0.6, 1.0])))
        after = camera.render()
        again = Camera(scene_world, config, 'egl')
        try:
            fresh = again.render()
        finally:
            again.close()
    finally:
        camera.close()
    assert not np.array_equal(before.rgb, after.rgb)
    assert np.array_equal(after.rgb, fresh.rgb)
    assert np.array_equal(after.depth, fresh.depth)


@needs_egl
def test_a_world_of_more_shapes_than_one_draw_holds_is_drawn_whole():
    """Shapes go to OpenGL 256 to a draw: the ones past the first draw show as TinyRenderer's."""
    world = SimWorld(WorldConfig())
    try:
        grid = [(x, y) for x in np.linspace(0.15, 0.85, 15) for y in np.linspace(-0.75, 0.45, 19)
                if np.hypot(x, y) > 0.25]
        assert len(grid) > 256
        for i, (x, y) in enumerate(grid):
            world.add_box((x, y, 0.02), (0.015, 0.015, 0.02), (i % 7 / 6, 0.5, 1 - i % 5 / 4, 1),
                          mass=0)
        gl, tiny = Camera(world, CameraConfig(), 'egl'), Camera(world, CameraConfig(), 'tiny')
        try:
            ours, theirs = gl.render(), tiny.render()
        finally:
            gl.close()
    finally:
        world.close()
    both = np.isfinite(ours.depth) & np.isfinite(theirs.depth)
    within = np.abs(ours.depth[both] - theirs.depth[both]) < 0.001
    assert within.mean() >= 0.99, f'depth within 1 mm on {within.mean():.4f} of pixels'
    difference = np.abs(ours.rgb.astype(int) - theirs.rgb.astype(int)).max(axis=-1)
    assert np.mean(difference <= 2) >= 0.98


def test_an_unknown_renderer_is_refused_with_the_choices():
    with pytest.raises(RendererError, match="renderer must be auto, egl, tiny, got 'vulkan'"):
        choose_renderer('vulkan')


def test_tiny_is_chosen_when_asked_and_says_why():
    choice = choose_renderer('tiny')
    assert choice.name == 'tiny' and 'as asked' in choice.reason


class _StalledCamera(Camera):
    """An OpenGL camera whose drawing waits until released, as on an overloaded machine."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.release = threading.Event()
        self.drawing = threading.Event()
        self.stall = False

    def draw(self, snapshot):
        if self.stall:
            self.drawing.set()
            self.release.wait(30)
        return super().draw(snapshot)


class _Outputs:
    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.joint_stamps: list[int] = []
        self.frame_stamps: list[int] = []
        self.dropped = 0

    def clock(self, stamp_ns):
        pass

    def joint_states(self, stamp_ns, world):
        with self.lock:
            self.joint_stamps.append(stamp_ns)

    def frame(self, stamp_ns, camera, frame):
        with self.lock:
            self.frame_stamps.append(stamp_ns)

    def frame_dropped(self, stamp_ns, dropped):
        with self.lock:
            self.dropped = dropped


@needs_egl
def test_a_stalled_render_drops_frames_not_joint_states():
    world = SimWorld(WorldConfig())
    camera = _StalledCamera(world, CameraConfig(width=160, height=120), 'egl')
    outputs = _Outputs()
    loop = SimulationLoop(world, outputs, Schedule(joint_state_rate=100.0, camera_rate=30.0),
                          camera)
    loop.start()
    try:
        wait_for(lambda: len(outputs.frame_stamps) >= 3, 30, 'camera frames')
        camera.stall = True
        wait_for(camera.drawing.is_set, 30, 'a frame being drawn')
        stalled_at = loop.sim_time_ns
        # While the render hangs, a second of simulation time passes with its joint states.
        wait_for(lambda: loop.sim_time_ns >= stalled_at + NS, 60, 'physics past the stall')
        with outputs.lock:
            during = [s for s in outputs.joint_stamps if stalled_at < s <= stalled_at + NS]
            frames_during = [s for s in outputs.frame_stamps if s > stalled_at]
        assert len(during) >= 99  # 100 Hz of simulation time
        assert frames_during == []
        assert outputs.dropped >= 25
        camera.stall = False
        camera.release.set()
        count = len(outputs.frame_stamps)
        wait_for(lambda: len(outputs.frame_stamps) >= count + 3, 30, 'frames after the stall')
        assert 'dropped' in loop.summary()
    finally:
        camera.release.set()
        assert loop.stop()
        world.close()


def test_the_drop_warning_comes_once_and_only_when_drops_last():
    watch = DropWatch(window_s=5.0, share=0.5)
    period = NS // 30
    # One frame in ten dropped for a minute: never sustained.
    assert not any(watch.dropped(i * 10 * period, 30.0) for i in range(180))
    # Then every other frame: told once, after 5 s of it.
    start = 180 * 10 * period
    told = [watch.dropped(start + i * 2 * period, 30.0) for i in range(300)]
    assert told.count(True) == 1 and 60 <= told.index(True) <= 76
