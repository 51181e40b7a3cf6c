"""The viewer page in a real headless browser: Debian's chromium driven by selenium.

As root (CI) the fixture installs chromium and chromium-driver with apt-get when missing;
elsewhere, without them, these tests are skipped with the reason.
"""

from collections.abc import Iterator
import math
import os
import re
import shutil
import subprocess
import tempfile

from conftest import wait_for
import cv2
import numpy as np
import pytest
from rclpy.parameter import Parameter
from selenium import webdriver
from selenium.common.exceptions import WebDriverException
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By
from sensor_msgs.msg import JointState
from ur_rg2_sim.sim_node import SimNode
from ur_rg2_vision.viewer_node import ViewerNode
from ur_rg2_vision.vision_node import VisionNode

CHROMIUM = '/usr/bin/chromium'
CHROMEDRIVER = '/usr/bin/chromedriver'


def ensure_chromium() -> None:
    """Install Debian's chromium and its driver when root; skip the test when that can't be."""
    if os.path.isfile(CHROMIUM) and os.path.isfile(CHROMEDRIVER):
        return
    if os.geteuid() != 0 or not shutil.which('apt-get'):
        pytest.skip(f'headless browser test needs {CHROMIUM} and {CHROMEDRIVER}: run as root '
                    'or `apt-get install chromium chromium-driver`')
    env = dict(os.environ, DEBIAN_FRONTEND='noninteractive')
    for command in (['apt-get', 'update', '-qq'],
                    ['apt-get', 'install', '-y', '-qq', 'chromium', 'chromium-driver']):
        result = subprocess.run(command, env=env, capture_output=True, text=True, timeout=900)
        assert result.returncode == 0, f'{" ".join(command)} failed:\n{result.stderr[-2000:]}'


@pytest.fixture(scope='module')
def browser() -> Iterator[webdriver.Chrome]:
    """Yield a headless chromium with a fresh profile, no network of its own, no downloads."""
    ensure_chromium()
    with tempfile.TemporaryDirectory(prefix='viewer-chromium-') as profile:
        options = webdriver.ChromeOptions()
        options.binary_location = CHROMIUM
        for flag in ('--headless', '--no-sandbox', '--disable-gpu', '--disable-quic',
                     '--no-first-run', '--disable-background-networking',
                     '--disable-component-update', '--disable-sync', '--disable-dev-shm-usage',
                     '--window-size=1080,760', f'--user-data-dir={profile}'):
            options.add_argument(flag)
        # An explicit driver path: selenium then never runs Selenium Manager (no download).
        driver = webdriver.Chrome(options=options, service=Service(CHROMEDRIVER))
        try:
            driver.set_page_load_timeout(30)
            yield driver
        finally:
            driver.quit()


def shown_frame(driver: webdriver.Chrome) -> np.ndarray | None:
    """Return the stream <img> as the browser renders it (BGR), or None before a frame."""
    try:
        image = driver.find_element(By.ID, 'stream')
        if not driver.execute_script('return arguments[0].naturalWidth', image):
            return None
        return cv2.imdecode(np.frombuffer(image.screenshot_as_png, np.uint8), cv2.IMREAD_COLOR)
    except WebDriverException:
        return None


def shown_angle(driver: webdriver.Chrome, joint: str) -> str | None:
    """Return the angle text the page shows for ``joint`` (e.g. '28.6°'), None if absent."""
    cells = driver.find_elements(By.CSS_SELECTOR, f'#joint-{joint} td')
    return cells[0].text if cells else None


def non_blank_frame(driver: webdriver.Chrome) -> list[np.ndarray]:
    """Return ``[frame]`` when the page shows a frame with some contrast, else ``[]``."""
    frame = shown_frame(driver)
    return [frame] if frame is not None and frame.std() > 10 else []


def test_page_follows_the_simulator(ros_graph, browser):
    # scripts/viewer-screenshot saves docs/reference.md's picture at the default camera size; the
    # test alone renders a smaller image to leave the two cores to the browser and the nodes.
    screenshot = os.environ.get('VIEWER_SCREENSHOT')
    width, height = (640, 480) if screenshot else (320, 240)
    sim = ros_graph.add(SimNode(context=ros_graph.context, parameter_overrides=[
        Parameter('camera_width', value=width), Parameter('camera_height', value=height)]))
    ros_graph.add(VisionNode(context=ros_graph.context))
    viewer = ros_graph.add(ViewerNode(context=ros_graph.context, parameter_overrides=[
        Parameter('port', value=0)]))
    jog = ros_graph.node('jogger').create_publisher(JointState, 'joint_jog', 10)

    browser.get(viewer.url)
    assert browser.title == 'UR + RG2 live view'
    wait_for(lambda: shown_angle(browser, 'shoulder_pan_joint') == '0.0°', 60,
             'the page to show the home pose')
    [before] = wait_for(lambda: non_blank_frame(browser), 30, 'a non-blank frame in the page')
    wait_for(lambda: browser.find_element(By.ID, 'ball').text.startswith('x '), 30,
             'the page to show the ball position found by vision')
    world = wait_for(lambda: re.fullmatch(
        r"x (\S+) y (\S+) z (\S+) m in world, (?:from the sim's camera pose|through the "
        r"transform tree)",
        browser.find_element(By.ID, 'ball-world').text), 30, 'the ball in world coordinates')
    # Where the sim put it, to within a centimetre or two (the depth camera's error).
    assert [float(value) for value in world.groups()] == pytest.approx(
        sim.get_parameter('ball_position').value, abs=0.02)
    wait_for(jog.get_subscription_count, 10, 'the sim to subscribe to joint_jog')

    jog.publish(JointState(name=['shoulder_pan_joint'], position=[0.6]))
    wait_for(lambda: abs(float(shown_angle(browser, 'shoulder_pan_joint').rstrip('°'))
                         - math.degrees(0.6)) < 1.0, 30,
             'the page to show shoulder_pan_joint at 34.4° after the jog')
    wait_for(lambda: any(np.abs(after.astype(int) - before.astype(int)).mean() > 2
                         for after in non_blank_frame(browser)), 30,
             'the frame shown in the page to change as the arm moves', interval=0.1)
    if screenshot:
        browser.save_screenshot(screenshot)
