"""ROS 1 bags with a missing or damaged index: read without it up to the damage, or one line."""

import dataclasses
import struct

from bag_helpers import drive_messages, room_drive, write_ros1_bag
import numpy as np
from polyline_mapper.cli import main
from polyline_mapper.formats.bag import BagError, BagReader
import pytest

U32 = struct.Struct('<L')
COMPRESSIONS = [None, 'bz2', 'lz4']


@pytest.fixture(scope='module')
def drive():
    return room_drive(step=0.5, rng=11)


@pytest.fixture(scope='module', params=COMPRESSIONS, ids=['none', 'bz2', 'lz4'])
def intact(request, drive, tmp_path_factory):
    """Write an intact ROS 1 bag of 4 chunks; return, its bytes, layout and records."""
    folder = tmp_path_factory.mktemp('ros1')
    path = write_ros1_bag(folder / 'ok.bag', drive_messages(drive), chunk_bytes=20000,
                          compression=request.param)
    data = open(path, 'rb').read()
    with BagReader(path, odometry=True) as bag:
        assert bag.warnings == [] and bag.reindexed is None
        records = list(bag.messages())
    return request.param, data, layout(path, data, request.param), records


def layout(path, data, compression):
    """Chunks (header pos, data pos, data size); per message, where it and its chunk end."""
    from rosbags.rosbag1 import Reader
    with Reader(path) as r:
        chunks = sorted((p, c.datapos, c.datasize) for p, c in r.chunks.items())
        ends = []
        for conn in r.connections:
            for entry in r.indexes[conn.id]:
                chunk = r.chunks[entry.chunk_pos]
                end = chunk.datapos + chunk.datasize
                if compression is None:            # the message record itself
                    at = chunk.datapos + entry.offset
                    hlen = U32.unpack_from(data, at)[0]
                    end = at + 8 + hlen + U32.unpack_from(data, at + 4 + hlen)[0]
                ends.append((end, chunk.datapos + chunk.datasize))
    index_pos = struct.unpack_from('<Q', data, data.index(b'index_pos=') + 10)[0]
    return {'chunks': chunks, 'ends': ends, 'index_pos': index_pos}


def kept(lay, compression, cut):
    """Count the messages a reader without the index can give from the first ``cut`` bytes."""
    return sum((rec if compression is None else chunk) <= cut for rec, chunk in lay['ends'])


def set_index_pos(data, value):
    at = data.index(b'index_pos=') + 10
    return data[:at] + struct.pack('<Q', value) + data[at + 8:]


def unclosed_chunk(data, pos):
    """Zero the sizes of the chunk at byte ``pos``, as the ROS 1 recorder leaves an open one."""
    hlen = U32.unpack_from(data, pos)[0]
    head = data[pos + 4:pos + 4 + hlen]
    size_at = pos + 4 + head.index(b'size=') + 5
    out = bytearray(data)
    out[size_at:size_at + 4] = bytes(4)
    out[pos + 4 + hlen:pos + 8 + hlen] = bytes(4)
    return bytes(out)


def damage(kind, data, lay, compression):
    """Return (damaged bytes, messages expected: None for all, a line the warning holds)."""
    idx, chunks = lay['index_pos'], lay['chunks']
    if kind == 'crash, no index':           # closed chunks, index never written
        return set_index_pos(data[:idx], 0), None, 'no index'
    if kind == 'cut inside a chunk':        # a copy cut short: the index is gone
        cut = chunks[2][1] + chunks[2][2] // 2
        return data[:cut], kept(lay, compression, cut), 'truncated'
    if kind == 'recorder crash in an open chunk':
        pos, datapos, datasize = chunks[-1]
        cut = datapos + (datasize * 3 // 5 if compression is None else 0)
        bad = unclosed_chunk(set_index_pos(data, 0), pos)[:cut]
        return bad, kept(lay, compression, cut), 'no index'
    if kind == 'index zeroed':
        return data[:idx] + bytes(len(data) - idx), None, 'unreadable records'
    if kind == 'index position wrong':
        return set_index_pos(data, 5000), None, 'index records unreadable'
    if kind == 'chunk index data damaged':      # rosbags: a bare AssertionError
        at = data.index(b'op=\x04')
        return data[:at - 8] + U32.pack(48) + data[at - 4:], None, 'malformed index records'
    raise AssertionError(kind)


def key(record):
    """Return a comparable form of a record (arrays as bytes): equal keys, equal bits."""
    if isinstance(record, list):
        return tuple(key(r) for r in record)
    return (type(record).__name__,) + tuple(
        (f.name, v.dtype.str, v.tobytes()) if isinstance(v, np.ndarray) else (f.name, v)
        for f in dataclasses.fields(record) for v in [getattr(record, f.name)])


@pytest.mark.parametrize('kind', ['crash, no index', 'cut inside a chunk',
                                  'recorder crash in an open chunk', 'index zeroed',
                                  'index position wrong', 'chunk index data damaged'])
def test_a_bag_with_a_bad_index_gives_the_intact_records_up_to_the_damage(tmp_path, intact,
                                                                          kind):
    compression, data, lay, want = intact
    bad, count, note = damage(kind, data, lay, compression)
    count = len(want) if count is None else count
    assert 0 < count <= len(want)
    path = tmp_path / 'bad.bag'
    path.write_bytes(bad)
    with BagReader(str(path), odometry=True) as bag:
        got = list(bag.messages())
        warnings = bag.warnings
        assert bag.scan_count == sum(topic == '/scan' for _, topic, _ in got)
        assert bag.reindexed.messages == count
    assert [(t, topic, key(r)) for t, topic, r in got] == \
        [(t, topic, key(r)) for t, topic, r in want[:count]]
    assert len(warnings) == 1 and '\n' not in warnings[0], warnings
    line = warnings[0]
    assert 'ROS 1 bag index is missing or damaged' in line and 'rebuilt in memory' in line
    assert f'{count} message(s)' in line and 'chunk(s)' in line and note in line, line
    cut_short = kind in ('cut inside a chunk', 'recorder crash in an open chunk')
    assert ('truncated' in line) == cut_short, line


@pytest.mark.parametrize('name, tail, reason', [
    ('junk.bag', bytes(range(256)) * 50, 'no readable message'),
    ('zeros.bag', bytes(30000), 'no readable message'),
    ('header-only.bag', b'', 'no readable message'),
])
def test_a_bag_with_nothing_readable_after_its_header_is_one_line(
        tmp_path, capsys, intact, name, tail, reason):
    _, data, _, _ = intact
    path = tmp_path / name
    path.write_bytes(set_index_pos(data[:4096 + 13], 0) + tail)
    with pytest.raises(BagError) as err:
        BagReader(str(path)).open_bag()
    text = str(err.value)
    assert '\n' not in text and text.startswith(str(path))
    assert 'ROS 1 bag index is missing or damaged' in text and reason in text, text
    assert 'AssertionError' not in text
    out = tmp_path / 'm.json'
    assert main(['replay', str(path), '-o', str(out), '-q']) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('polyline-mapper: error: '), lines
    assert 'index is missing or damaged' in lines[0], lines
    assert not out.exists()
    # Not a ROS 1 bag of format 2.0 at all: rosbags' reason, no scan.
    path.write_bytes(b'#ROSBAG V1.2\n' + tail)
    with pytest.raises(BagError, match='cannot open the bag .*version'):
        BagReader(str(path)).open_bag()


def test_random_damage_to_an_index_less_bag_never_escapes(tmp_path, intact):
    compression, data, lay, want = intact
    base = set_index_pos(data[:lay['index_pos']], 0)
    rng = np.random.default_rng(8)
    outcomes = set()
    for k in range(25):
        bad = bytearray(base)
        start = int(rng.integers(4096, len(base) - 8))
        n = int(rng.integers(1, 64))
        bad[start:start + n] = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        path = tmp_path / f'bad{k}.bag'
        path.write_bytes(bytes(bad))
        try:
            with BagReader(str(path), odometry='auto') as bag:
                got = list(bag.records())
                assert len(bag.warnings) == 1 and bag.reindexed is not None
            assert 0 < len(got)
            outcomes.add('read')
        except BagError as exc:
            assert '\n' not in str(exc)
            outcomes.add('error')
    assert 'read' in outcomes


def test_replay_of_a_bag_without_its_index_says_the_index_was_rebuilt(tmp_path, intact, capsys):
    compression, data, lay, want = intact
    path = tmp_path / 'noindex.bag'
    path.write_bytes(set_index_pos(data[:lay['index_pos']], 0))
    out = tmp_path / 'm.json'
    assert main(['replay', str(path), '-o', str(out), '-q']) == 0
    err = capsys.readouterr().err
    assert 'warning' in err and 'index rebuilt in memory' in err, err
    assert out.exists()
