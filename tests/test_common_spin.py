"""ur_rg2_common.spin.keep_freed_memory: image-sized buffers are reused, not faulted in anew."""

import resource

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
