"""The viewer page in a real headless browser: Debian's chromium driven by selenium.

As root (CI) the fixture installs chromium and chromium-driver with apt-get when missing;
elsewhere, without them, these tests are skipped with the reason.
"""

from collections.abc import Iterator
import os
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
from sensor_msgs.msg import Image, JointState
from ur_rg2_vision.viewer_node import ViewerNode

CHROMIUM = '/usr/bin/chromium'
CHROMEDRIVER = '/usr/bin/chromedriver'
ARM = ['shoulder_pan_joint', 'shoulder_lift_joint', 'elbow_joint', 'wrist_1_joint',
       'wrist_2_joint', 'wrist_3_joint']


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
                     '--window-size=1100,640', f'--user-data-dir={profile}'):
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


def assert_stream_is_live(driver: webdriver.Chrome, change) -> None:
    """Assert the page shows non-blank frames that change after ``change()`` is called."""
    def non_blank() -> list[np.ndarray]:
        frame = shown_frame(driver)
        return [frame] if frame is not None and frame.std() > 10 else []

    [first] = wait_for(non_blank, 20, 'a non-blank frame in the page')

    def changed() -> bool:
        change()
        return any(np.abs(frame.astype(int) - first.astype(int)).mean() > 2
                   for frame in non_blank())

    wait_for(changed, 20, 'the frame shown in the page to change', interval=0.1)


def test_page_shows_live_stream_and_joint_angles(ros_graph, browser):
    viewer = ros_graph.add(ViewerNode(context=ros_graph.context, parameter_overrides=[
        Parameter('port', value=0)]))
    fake = ros_graph.node('fake_graph')
    images = fake.create_publisher(Image, 'ball/image', 10)
    joints = fake.create_publisher(JointState, 'joint_states', 10)
    wait_for(lambda: images.get_subscription_count() and joints.get_subscription_count(), 10,
             'the viewer to subscribe')
    ticks = [0]

    def publish(pan: float) -> None:
        # A white square that moves one step per call on a grey ramp.
        ticks[0] += 1
        frame = np.tile(np.linspace(40, 120, 320, dtype=np.uint8)[None, :, None], (240, 1, 3))
        x = 10 + ticks[0] * 7 % 260
        frame[100:150, x:x + 50] = 255
        images.publish(Image(height=240, width=320, encoding='rgb8', step=960,
                             data=frame.tobytes()))
        joints.publish(JointState(name=ARM, position=[pan, 0.0, 0.0, 0.0, 0.0, 0.0]))

    publish(0.5)
    browser.get(viewer.url)
    assert browser.title == 'UR + RG2 live view'
    wait_for(lambda: (publish(0.5), shown_angle(browser, 'shoulder_pan_joint') == '28.6°')[1],
             20, 'the page to show 28.6° for shoulder_pan_joint')
    assert_stream_is_live(browser, lambda: publish(0.5))
    wait_for(lambda: (publish(-1.0), shown_angle(browser, 'shoulder_pan_joint') == '-57.3°')[1],
             20, 'the page to follow the joint to -57.3°')
