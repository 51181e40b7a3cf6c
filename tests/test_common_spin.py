"""ur_rg2_common.spin: freed image-sized buffers are reused; a stop signal is a clean stop."""

import os
import resource
import subprocess
import sys

from conftest import next_domain_id
import numpy as np
from ur_rg2_common.spin import keep_freed_memory

IMAGE_BYTES = 640 * 480 * 3


def page_faults_per_image(images: int = 30) -> float:
    """Return the minor page faults per image-sized buffer made, filled and freed."""
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(images):
        buffer = np.ones(IMAGE_BYTES, np.uint8)
        del buffer
    return (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / images


def test_freed_image_buffers_are_reused():
    keep_freed_memory()
    page_faults_per_image()  # the first one may grow the heap
    # A fresh 900 kB buffer would touch 225 new pages.
    assert page_faults_per_image() < 5


NODE_STOPPED_IN_A_CALLBACK = """
import os, signal, sys, time
from rclpy.node import Node
from ur_rg2_common.spin import run_node

class Taker(Node):
    def __init__(self):
        super().__init__('taker')
        self.create_timer(0.01, self.take)

    def take(self):
        # As rclpy's C++ does when the SIGINT's KeyboardInterrupt hits it mid-conversion.
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(5)  # the SIGINT ends it at once
        except KeyboardInterrupt:
            raise RuntimeError("Unable to convert call argument '0' to Python object")

sys.exit(run_node(Taker, None, 'taker'))
"""


def test_a_sigint_that_surfaces_as_another_error_in_a_callback_is_a_clean_stop():
    env = dict(os.environ, ROS_DOMAIN_ID=str(next_domain_id()),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    done = subprocess.run([sys.executable, '-c', NODE_STOPPED_IN_A_CALLBACK], env=env,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert 'Traceback' not in done.stderr and 'stopped:' not in done.stderr, done.stderr
