"""Image message conversion and frame files of the vision package (no ROS graph)."""

import errno
import os

import cv2
import numpy as np
import pytest
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header
from ur_rg2_vision import frame_store
from ur_rg2_vision.frame_store import depth_to_mm, save_frame
from ur_rg2_vision.ros_image import camera_matrix, image_to_depth, image_to_rgb, rgb_to_image

RGB = np.arange(4 * 5 * 3, dtype=np.uint8).reshape(4, 5, 3)


def image(array: np.ndarray, encoding: str, pad: int = 0, bigendian: bool = False) -> Image:
    """Return an Image of ``array`` whose rows are padded by ``pad`` bytes."""
    height, width = array.shape[:2]
    rows = array.reshape(height, -1).view(np.uint8)
    padded = np.concatenate([rows, np.full((height, pad), 0xEE, np.uint8)], axis=1)
    return Image(height=height, width=width, encoding=encoding, is_bigendian=int(bigendian),
                 step=padded.shape[1], data=padded.tobytes())


@pytest.mark.parametrize('pad', [0, 3])
@pytest.mark.parametrize('encoding, array', [
    ('rgb8', RGB), ('bgr8', RGB[:, :, ::-1]),
    ('rgba8', np.dstack([RGB, np.full((4, 5), 9, np.uint8)])),
    ('bgra8', np.dstack([RGB[:, :, ::-1], np.full((4, 5), 9, np.uint8)])),
])
def test_colour_encodings_and_row_padding(encoding, array, pad):
    rgb = image_to_rgb(image(np.ascontiguousarray(array), encoding, pad))
    assert rgb.flags.c_contiguous
    np.testing.assert_array_equal(rgb, RGB)


def test_depth_32fc1_with_padding_and_either_byte_order():
    depth = np.array([[0.5, np.inf], [np.nan, 2.25]], np.float32)
    np.testing.assert_array_equal(image_to_depth(image(depth, '32FC1', pad=4)), depth)
    big = image(depth.astype('>f4'), '32FC1', bigendian=True)
    np.testing.assert_array_equal(image_to_depth(big), depth)


def test_depth_16uc1_millimetres_zero_is_no_return():
    depth = image_to_depth(image(np.array([[0, 1500]], np.uint16), '16UC1'))
    assert np.isnan(depth[0, 0]) and depth[0, 1] == pytest.approx(1.5)


@pytest.mark.parametrize('convert, msg, reason', [
    (image_to_rgb, image(RGB, 'mono16'), 'unsupported colour encoding'),
    (image_to_depth, image(RGB, 'rgb8'), 'unsupported depth encoding'),
    (image_to_rgb, Image(height=4, width=5, encoding='rgb8', step=15, data=b'x' * 59),
     'data has 59 bytes'),
    (image_to_rgb, Image(height=4, width=5, encoding='rgb8', step=14, data=b'x' * 60), 'step'),
    (image_to_rgb, Image(height=0, width=5, encoding='rgb8', step=15), 'empty'),
])
def test_unreadable_images_raise_value_error_with_reason(convert, msg, reason):
    with pytest.raises(ValueError, match=reason):
        convert(msg)


def test_rgb_to_image_round_trip():
    header = Header(frame_id='camera_color_optical_frame')
    msg = rgb_to_image(RGB, header)
    assert (msg.encoding, msg.step, msg.header.frame_id) == ('rgb8', 15, header.frame_id)
    np.testing.assert_array_equal(image_to_rgb(msg), RGB)


def test_camera_matrix():
    k = camera_matrix(CameraInfo(k=[500.0, 0, 320, 0, 500, 240, 0, 0, 1]))
    assert k.shape == (3, 3) and k[0, 2] == 320
    with pytest.raises(ValueError):
        camera_matrix(CameraInfo())  # all zeros: no focal length
    with pytest.raises(ValueError):
        camera_matrix(CameraInfo(k=[np.nan, 0, 320, 0, 500, 240, 0, 0, 1]))


# -- frame files ---------------------------------------------------------------------------

def test_depth_to_mm_rounds_and_zeroes_no_return():
    depth = np.array([0.0004, 0.0006, 1.2344, 65.535, 65.6, -1.0, 0.0, np.nan, np.inf],
                     np.float32)
    assert depth_to_mm(depth).tolist() == [0, 1, 1234, 65535, 0, 0, 0, 0, 0]


# 2026-11-23 14:08:48.123456 UTC, when a frame was saved
WALL = 1795442928.123456
STEM = 'frame_20261123T140848.123Z_sim0000000012.005000000'


def test_save_frame_writes_colour_and_depth_pngs_named_by_wall_clock_and_stamp(tmp_path):
    rgb = np.random.default_rng(1).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    depth = np.full((48, 64), 1.5, np.float32)
    depth[0, 0] = np.inf
    directory = tmp_path / 'new' / 'frames'
    paths = save_frame(str(directory), 12, 5_000_000, rgb, depth, wall_time=WALL)
    assert [os.path.basename(p) for p in paths] == [f'{STEM}_color.png', f'{STEM}_depth.png']
    np.testing.assert_array_equal(cv2.cvtColor(cv2.imread(paths[0]), cv2.COLOR_BGR2RGB), rgb)
    saved_depth = cv2.imread(paths[1], cv2.IMREAD_UNCHANGED)
    assert saved_depth.dtype == np.uint16
    assert saved_depth[0, 0] == 0 and saved_depth[1, 1] == 1500
    assert sorted(os.listdir(directory)) == sorted(os.path.basename(p) for p in paths)


def test_save_frame_without_depth(tmp_path):
    paths = save_frame(str(tmp_path), 12, 5_000_000, RGB, None, wall_time=WALL)
    assert [os.path.basename(p) for p in paths] == [f'{STEM}_color.png']


def test_a_second_run_keeps_the_first_runs_frames(tmp_path):
    """Simulation time starts at 0 in every run: the same stamps must not replace old files."""
    first = save_frame(str(tmp_path), 0, 500_000_000, RGB, np.ones((4, 5), np.float32))
    second = save_frame(str(tmp_path), 0, 500_000_000, RGB[::-1].copy(),
                        np.full((4, 5), 2.0, np.float32))
    assert not set(first) & set(second)
    assert sorted(os.listdir(tmp_path)) == sorted(os.path.basename(p) for p in first + second)
    np.testing.assert_array_equal(cv2.imread(first[1], cv2.IMREAD_UNCHANGED), 1000)
    np.testing.assert_array_equal(cv2.imread(second[1], cv2.IMREAD_UNCHANGED), 2000)


@pytest.mark.parametrize('existing', ['color', 'depth'])
def test_an_existing_file_is_never_replaced(tmp_path, existing):
    """Same wall-clock millisecond and stamp (or a file of that name): the next name is used."""
    (tmp_path / f'{STEM}_{existing}.png').write_bytes(b'precious')
    paths = save_frame(str(tmp_path), 12, 5_000_000, RGB, np.ones((4, 5), np.float32),
                       wall_time=WALL)
    assert [os.path.basename(p) for p in paths] == [f'{STEM}_1_color.png', f'{STEM}_1_depth.png']
    assert (tmp_path / f'{STEM}_{existing}.png').read_bytes() == b'precious'
    assert sorted(os.listdir(tmp_path)) == sorted(
        [f'{STEM}_{existing}.png'] + [os.path.basename(p) for p in paths])
    again = save_frame(str(tmp_path), 12, 5_000_000, RGB, None, wall_time=WALL)
    assert [os.path.basename(p) for p in again] == [f'{STEM}_2_color.png']


def test_without_hard_links_files_still_appear_whole_and_never_replace(tmp_path, monkeypatch):
    """Some file systems (FAT, some network mounts) refuse hard links."""
    def no_link(source, destination):
        raise OSError(errno.EPERM, 'Operation not permitted')

    monkeypatch.setattr(frame_store.os, 'link', no_link)
    (tmp_path / f'{STEM}_color.png').write_bytes(b'precious')
    paths = save_frame(str(tmp_path), 12, 5_000_000, RGB, None, wall_time=WALL)
    assert [os.path.basename(p) for p in paths] == [f'{STEM}_1_color.png']
    assert (tmp_path / f'{STEM}_color.png').read_bytes() == b'precious'
    np.testing.assert_array_equal(cv2.cvtColor(cv2.imread(paths[0]), cv2.COLOR_BGR2RGB), RGB)
    assert sorted(os.listdir(tmp_path)) == [f'{STEM}_1_color.png', f'{STEM}_color.png']


@pytest.mark.parametrize('umask, mode', [(0o022, 0o644), (0o027, 0o640), (0o002, 0o664)])
def test_saved_files_get_the_mode_of_new_files(tmp_path, umask, mode):
    previous = os.umask(umask)
    try:
        paths = save_frame(str(tmp_path), 1, 2, RGB, np.ones((4, 5), np.float32))
    finally:
        os.umask(previous)
    assert [oct(os.stat(p).st_mode & 0o777) for p in paths] == [oct(mode)] * 2


def test_unwritable_directory_raises_and_leaves_nothing(tmp_path):
    blocker = tmp_path / 'a_file'
    blocker.write_text('not a directory')
    with pytest.raises(OSError):
        save_frame(str(blocker / 'frames'), 1, 2, RGB, None)
    assert os.listdir(tmp_path) == ['a_file']


def test_full_disk_leaves_no_partial_file(tmp_path, monkeypatch):
    """The depth write fails (disk full): neither its temp file nor the colour file stays."""
    real_fsync = os.fsync
    calls = []

    def fsync(fd):
        calls.append(fd)
        if len(calls) == 2:
            raise OSError(errno.ENOSPC, 'No space left on device')
        real_fsync(fd)

    monkeypatch.setattr(frame_store.os, 'fsync', fsync)
    with pytest.raises(OSError, match='No space left'):
        save_frame(str(tmp_path), 1, 2, RGB, np.ones((4, 5), np.float32))
    assert os.listdir(tmp_path) == []
