"""MCAP files of ur_rg2_tools without a graph: schemas, writing, reading, cut-short files."""

import errno
import io
from pathlib import Path
import re

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import pytest
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState
from ur_rg2_tools.backlog import WriteBacklog
from ur_rg2_tools.bag import (
    BagWriter,
    RecordingError,
    offered_qos_yaml,
    open_recording,
    readable_records,
    recorded_qos,
    recover,
)
from ur_rg2_tools.info import format_info, read_info
from ur_rg2_tools.info import main as info_main
from ur_rg2_tools.msgdefs import DELIMITER, DefinitionNotFoundError, full_text, msg_file
import yaml


def joint_state(i: int) -> JointState:
    message = JointState(name=['shoulder_pan_joint'], position=[i * 0.001])
    message.header.stamp.sec, message.header.stamp.nanosec = i, 1000 * i
    return message


# Serialized once: CDR's padding bytes are whatever the buffer held, so two serializations of a
# message can differ.
STATES = [serialize_message(joint_state(i)) for i in range(5000)]


def write_states(output, count: int, chunk_size: int = 4096) -> BagWriter:
    bag = BagWriter(output, chunk_size=chunk_size)
    qos = offered_qos_yaml([QoSProfile(depth=10)])
    channel = bag.add_topic('/joint_states', 'sensor_msgs/msg/JointState',
                            full_text('sensor_msgs/msg/JointState'), qos, 'RIHS01_00')
    for i in range(count):
        bag.write(channel, STATES[i], 10 ** 9 + i * 10 ** 7, 10 ** 9 + i * 10 ** 7, i)
    return bag


def test_schema_is_rosbag2s_complete_ros2msg_text():
    text = full_text('sensor_msgs/msg/JointState')
    own = msg_file('sensor_msgs/msg/JointState').read_text()
    assert text.startswith(own)  # the type's own .msg first, with no delimiter
    sections = text.split('\n' + DELIMITER)
    names = [section.split('\n', 1)[0] for section in sections[1:]]
    # Each type used once, named as the field spells it; Header's Time after Header.
    assert names == ['MSG: std_msgs/Header', 'MSG: builtin_interfaces/Time']
    with pytest.raises(DefinitionNotFoundError):
        full_text('no_such_msgs/msg/Thing')


def test_written_file_reads_back_with_the_mcap_reader(tmp_path):
    path = tmp_path / 'states.mcap'
    write_states(path, 50).finish()
    with open(path, 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == 'ros2'
        decoded = list(reader.iter_decoded_messages())
    assert len(decoded) == 50
    schema, channel, message, ros_message = decoded[7]
    assert (schema.name, schema.encoding) == ('sensor_msgs/msg/JointState', 'ros2msg')
    assert (channel.topic, channel.message_encoding) == ('/joint_states', 'cdr')
    assert message.data == STATES[7]  # the bytes as given, not re-encoded
    assert ros_message.header.stamp.sec == 7 and ros_message.position == [0.007]
    offered = yaml.safe_load(channel.metadata['offered_qos_profiles'])
    assert offered[0]['reliability'] == 'reliable' and offered[0]['history'] == 'keep_last'
    assert channel.metadata['topic_type_hash'] == 'RIHS01_00'


def test_latched_qos_is_kept_for_replay():
    latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                         reliability=ReliabilityPolicy.RELIABLE)

    class Channel:
        metadata = {'offered_qos_profiles': offered_qos_yaml([latched])}

    recorded = recorded_qos(Channel)
    assert (recorded['durability'], recorded['depth']) == ('transient_local', 1)
    Channel.metadata = {'offered_qos_profiles': ': not yaml ['}
    assert recorded_qos(Channel) == {}


def test_recording_never_overwrites_a_file(tmp_path):
    path = tmp_path / 'kept.mcap'
    path.write_bytes(b'precious')
    with pytest.raises(FileExistsError):
        BagWriter(path)
    assert path.read_bytes() == b'precious'


def test_cut_short_file_is_refused_and_its_chunks_recovered(tmp_path):
    whole = tmp_path / 'whole.mcap'
    write_states(whole, 400).finish()
    data = whole.read_bytes()
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(data[:len(data) * 2 // 3])  # as a recorder killed mid-chunk leaves it
    with pytest.raises(RecordingError, match='not a complete MCAP file.*recover'):
        open_recording(cut)
    result = recover(cut, tmp_path / 'fixed.mcap')
    assert result.error is not None and 0 < result.messages < 400
    fixed = open_recording(tmp_path / 'fixed.mcap')
    try:
        kept = [message.data for _, _, message in fixed.reader.iter_messages()]
    finally:
        fixed.stream.close()
    # Every message of the complete chunks, in order, as written.
    assert kept == STATES[:result.messages]
    assert open_recording(whole).message_count == 400


def test_bad_files_get_a_clear_error(tmp_path):
    with pytest.raises(RecordingError, match='cannot open .*No such file'):
        open_recording(tmp_path / 'missing.mcap')
    # No MCAP magic bytes: not an MCAP file, and no advice to recover it.
    (tmp_path / 'text.mcap').write_text('not a recording')
    with pytest.raises(RecordingError, match='not an MCAP file') as refused:
        open_recording(tmp_path / 'text.mcap')
    assert 'recover' not in str(refused.value)
    with pytest.raises(RecordingError, match='not an MCAP file'):
        recover(tmp_path / 'text.mcap', tmp_path / 'out.mcap')
    assert not (tmp_path / 'out.mcap').exists()


def test_info_prints_what_ros2_bag_info_prints(tmp_path, capsys):
    whole = tmp_path / 'whole.mcap'
    write_states(whole, 400).finish()
    assert info_main([str(whole)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[:3] == ['Files:             whole.mcap',
                         f'Bag size:          {whole.stat().st_size / 1024:.1f} KiB',
                         'Storage id:        mcap']
    assert 'Compression:       zstd' in lines
    assert 'Duration:          3.990000000s' in lines  # 400 messages 10 ms apart
    assert 'Start:             ' in lines[5] and lines[5].endswith('(1.000000000)')
    assert 'End:               ' in lines[6] and lines[6].endswith('(4.990000000)')
    assert 'Messages:          400' in lines
    assert ('Topic information: Topic: /joint_states | Type: sensor_msgs/msg/JointState | '
            'Count: 400 | Serialization Format: cdr') in lines
    assert not any(line.startswith('Cut short') for line in lines)


def test_info_reads_a_file_without_summary_through(tmp_path):
    whole = tmp_path / 'whole.mcap'
    write_states(whole, 400).finish()
    data = whole.read_bytes()
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(data[:len(data) * 2 // 3])
    info = read_info(cut)
    kept = recover(cut, tmp_path / 'fixed.mcap').messages
    assert info.messages == kept and [t.count for t in info.topics] == [kept]
    assert info.compression == ['zstd'] and info.cut_short is not None
    assert 'Cut short:' in format_info(info) and 'recover' in format_info(info)


@pytest.mark.parametrize('name, content, reason', [
    ('missing.mcap', None, 'cannot open .*missing.mcap: No such file or directory'),
    ('.', None, 'cannot open .*: Is a directory'),
    ('text.mcap', b'hello', "text.mcap is not an MCAP file \\(it does not start with MCAP's"),
    ('magic.mcap', b'\x89MCAP0\r\n', 'magic.mcap ends within its MCAP header'),
])
def test_info_on_bad_input_is_one_error_line_and_exit_1(tmp_path, capsys, name, content,
                                                         reason):
    if content is not None:
        (tmp_path / name).write_bytes(content)
    assert info_main([str(tmp_path / name)]) == 1
    out, err = capsys.readouterr()
    assert out == '' and len(err.splitlines()) == 1
    assert re.match(f'info: .*{reason}', err), err


class FullDisk(io.RawIOBase):
    """A file on a disk with room for ``room`` bytes: then every write fails with ENOSPC."""

    def __init__(self, room: int) -> None:
        self.data = bytearray()
        self.room = room

    def writable(self) -> bool:
        return True

    def write(self, data) -> int:
        space = self.room - len(self.data)
        if space <= 0:
            raise OSError(errno.ENOSPC, 'No space left on device')
        taken = bytes(data[:space])
        self.data += taken
        return len(taken)

    def tell(self) -> int:
        return len(self.data)


def test_full_disk_stops_writing_and_what_was_written_reads_back(tmp_path):
    disk = FullDisk(room=20_000)
    with pytest.raises(OSError) as failure:
        write_states(disk, 5000)
    assert failure.value.errno == errno.ENOSPC
    written = Path(tmp_path / 'full.mcap')
    written.write_bytes(disk.data)
    records = list(readable_records(io.BytesIO(bytes(disk.data))))
    messages = [record for record in records if type(record).__name__ == 'Message']
    assert messages and messages[0].data == STATES[0]
    result = recover(written, tmp_path / 'recovered.mcap')
    assert result.messages == len(messages)
    recovered = open_recording(tmp_path / 'recovered.mcap')
    try:
        first = next(iter(recovered.reader.iter_messages()))[2]
    finally:
        recovered.stream.close()
    assert list(deserialize_message(first.data, JointState).position) == [0.0]


def test_the_write_backlog_drops_past_its_size_and_counts_per_topic():
    backlog = WriteBacklog(max_bytes=1000)
    assert backlog.take('/image', 600) and backlog.take('/joint_states', 300)
    assert not backlog.take('/image', 600)  # 1500 > 1000: dropped
    assert backlog.take('/joint_states', 100)
    backlog.written(600)
    assert backlog.take('/image', 600) and backlog.held == 1000
    assert backlog.summary() == '1 (/image: 1)'
    # A message larger than the whole cache still goes through when nothing waits.
    empty = WriteBacklog(max_bytes=10)
    assert empty.take('/image', 100) and not empty.take('/image', 1)
    with pytest.raises(ValueError, match='must be positive'):
        WriteBacklog(0)
