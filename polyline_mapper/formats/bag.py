"""
Bags in and out with ``rosbags`` (pure Python, no ROS install): rosbag2 and ROS 1.

Reading: a rosbag2 folder (with metadata.yaml), a rosbag2 storage file itself (``.db3``,
``.mcap``) or a ROS 1 ``.bag``. ``BagReader`` streams, in recording order, plain records
(``formats.records``): ``Scan`` from one ``sensor_msgs/LaserScan`` topic (named, or the only one
in the bag), ``Odometry`` from one ``nav_msgs/Odometry`` topic when asked for, and a
``Transform`` for every transform on ``/tf`` and ``/tf_static`` (``tf2_msgs/TFMessage``), and a
``PoseEstimate`` for every ``geometry_msgs/PoseWithCovarianceStamped`` on ``/initialpose``. Stamps
are the messages' header stamps. A message that does not decode is yielded as ``Skipped``; a bag
that cannot be opened or read on (truncated, not a bag) raises ``BagError`` with one line.

A ROS 1 bag whose index is missing or damaged (a recording cut off by a crash, a damaged end of
file) is read without it, as ``rosbag reindex`` would (``ros1_reindex``): the index is rebuilt
in memory from the chunks, the records are those of the intact bag up to the damage, and
``BagReader.warnings`` says so in one line (messages, chunks, what was lost).

Writing: ``BagWriter`` writes rosbag2 (sqlite3 or mcap) from the same records.
"""

import os
import pathlib
import re
import sqlite3
import struct
from typing import Iterator, Optional

import numpy as np

from .records import clean_frame, Odometry, PoseEstimate, Scan, Skipped, Transform
from ..poses import checked_yaw, planar_covariance, pose_covariance, quaternion_from_yaw

SCAN_TYPE = 'sensor_msgs/msg/LaserScan'
ODOM_TYPE = 'nav_msgs/msg/Odometry'
TF_TYPES = ('tf2_msgs/msg/TFMessage', 'tf/msg/tfMessage')
TF_TOPICS = {'/tf': False, '/tf_static': True}
ESTIMATE_TOPIC, ESTIMATE_TYPE = '/initialpose', 'geometry_msgs/msg/PoseWithCovarianceStamped'
BAG_SUFFIXES = ('.db3', '.mcap', '.bag')


class BagError(ValueError):
    """A bag that cannot be used, with a one-line reason."""


ROSBAGS_MISSING = ('reading and writing bags needs the Python package rosbags, which is not '
                   'installed (it has no rosdep key): pip install rosbags')
"""The one line when ``rosbags`` does not import (a ROS install without it, see the README)."""


def _need_rosbags() -> None:
    """Raise BagError with ``ROSBAGS_MISSING`` when ``rosbags`` does not import."""
    try:
        import rosbags.highlevel  # noqa: F401
        import rosbags.rosbag2  # noqa: F401
    except ImportError:
        raise BagError(ROSBAGS_MISSING) from None


def is_bag(path) -> bool:
    """Return whether ``path`` looks like a bag: a rosbag2 folder or a .db3/.mcap/.bag file."""
    p = pathlib.Path(path)
    if p.is_dir():
        return (p / 'metadata.yaml').is_file()
    return p.suffix.lower() in BAG_SUFFIXES


def _read_errors() -> tuple:
    """Exceptions a damaged or foreign file can raise inside rosbags."""
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Reader1Error
    from rosbags.rosbag2 import ReaderError as Reader2Error
    try:
        from apsw import Error as ApswError          # rosbags' sqlite3 storage
    except ImportError:                               # pragma: no cover
        ApswError = sqlite3.Error
    try:                                              # rosbags' zstd: rosbag2 compression, mcap
        from compression.zstd import ZstdError       # chunks (Python >= 3.14)
    except ImportError:
        try:
            from backports.zstd import ZstdError
        except ImportError:                           # pragma: no cover
            ZstdError = ValueError
    # lz4.frame (mcap lz4 chunks, ROS 1 lz4 chunks) raises a bare RuntimeError on damaged data
    return (AnyReaderError, Reader1Error, Reader2Error, ApswError, sqlite3.Error, OSError,
            EOFError, struct.error, ValueError, IndexError, KeyError, TypeError,
            UnicodeDecodeError, AssertionError, ArithmeticError, MemoryError, RuntimeError,
            ZstdError)


def _stamp(header) -> float:
    return float(header.stamp.sec) + 1e-9 * float(header.stamp.nanosec)


def _vec(v) -> np.ndarray:
    return np.array([v.x, v.y, v.z], dtype=np.float64)


def _quat(q) -> np.ndarray:
    return np.array([q.x, q.y, q.z, q.w], dtype=np.float64)


class BagReader:
    """
    Stream the scans, odometry and transforms of a bag as plain records.

    For example, of a bag ``run.mcap`` of your own::

        with BagReader('run.mcap') as bag:
            print(bag.scan_topic, bag.scan_count)
            for record in bag.records():
                ...

    Parameters
    ----------
    path : str
        rosbag2 folder, .db3 / .mcap file, or ROS 1 .bag.
    scan_topic : str, optional
        LaserScan topic; by default the only one in the bag.
    odom_topic : str, optional
        Odometry topic (with ``odometry=True``); by default the only one in the bag.
    odometry : bool or 'auto'
        Also read odometry (True: required then; 'auto': when ``odom_topic`` is given or the
        bag has exactly one Odometry topic).
    transforms : bool
        Read /tf and /tf_static when the bag has them.

    """

    def __init__(self, path: str, scan_topic: str = None, odom_topic: str = None,
                 odometry=False, transforms: bool = True):
        self.path = str(path)
        self._want = (scan_topic, odom_topic, odometry, transforms)
        self._reader = None
        self.topics = {}
        self.scan_topic = None
        self.scan_count = 0
        self.odom_topic = None
        self.tf_topics = []
        self.estimate_topic = None
        self.warnings = []
        """One-line warnings about the bag (e.g. a ROS 1 index rebuilt in memory)."""
        self.reindexed = None
        """ScanReport when a ROS 1 bag was read without its index, else None."""

    # -- opening -------------------------------------------------------------------------------
    def __enter__(self) -> 'BagReader':
        """Open the bag and choose the topics; BagError when that fails."""
        self.open_bag()
        return self

    def __exit__(self, *exc) -> bool:
        """Close the bag."""
        self.close()
        return False

    def open_bag(self) -> None:
        """Open the bag and choose the topics; BagError when that fails."""
        _need_rosbags()
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import get_typestore, Stores
        p = pathlib.Path(self.path)
        if not p.exists():
            raise BagError(f'{self.path}: no such file or folder')
        if not is_bag(p):
            raise BagError(f'{self.path}: not a bag (expected a rosbag2 folder with '
                           'metadata.yaml, a .db3 / .mcap file or a ROS 1 .bag)')
        if p.is_file() and os.path.getsize(p) == 0:
            raise BagError(f'{self.path}: empty file')
        store = get_typestore(Stores.ROS1_NOETIC if p.suffix.lower() == '.bag'
                              else Stores.ROS2_JAZZY)
        try:
            reader = AnyReader([p], default_typestore=store)
            reader.open()
        except _read_errors() as exc:
            if p.suffix.lower() != '.bag' or not p.is_file():
                raise BagError(f'{self.path}: cannot open the bag ({_why(exc)})'
                               + _mcap_hint(p, exc)) from None
            reader = self._open_reindexed(p, store, exc)
        self._reader = reader
        try:
            self.topics = {name: info.msgtype for name, info in reader.topics.items()}
            self._choose(*self._want)
        except BaseException:
            self.close()
            raise

    def _open_reindexed(self, p: pathlib.Path, store, exc: BaseException):
        """Open a ROS 1 bag whose index rosbags rejects by scanning its chunks; BagError."""
        from rosbags.highlevel import AnyReader
        from .ros1_reindex import NotABagError, ReindexedReader, ReindexError
        why = _index_why(exc)
        reader = AnyReader([p], default_typestore=store)
        scan = ReindexedReader(p)
        reader.readers = [scan]            # rosbags' AnyReader over a reader opened by a scan
        try:
            reader.open()
        except NotABagError:
            raise BagError(f'{self.path}: cannot open the bag ({_why(exc)})') from None
        except ReindexError as err:
            raise BagError(f'{self.path}: ROS 1 bag index is missing or damaged ({why}) and '
                           f'the file cannot be read without it: {err}') from None
        except _read_errors() as err:
            raise BagError(f'{self.path}: ROS 1 bag index is missing or damaged ({why}) and '
                           f'the file cannot be read without it ({_why(err)})') from None
        self.reindexed = scan.report
        self.warnings.append(f'{self.path}: ROS 1 bag index is missing or damaged ({why}); '
                             'index rebuilt in memory from the chunks, as rosbag reindex would: '
                             f'{scan.report.describe()}')
        return reader

    def close(self) -> None:
        """Close the bag (safe to call twice)."""
        reader, self._reader = self._reader, None
        if reader is not None:
            try:
                reader.close()
            except _read_errors():
                pass

    def _count(self, topic: str) -> int:
        return int(self._reader.topics[topic].msgcount)

    def _choose(self, scan_topic, odom_topic, odometry, transforms) -> None:
        self.scan_topic = self._pick(scan_topic, SCAN_TYPE, 'LaserScan', '--scan-topic')
        self.scan_count = self._count(self.scan_topic)
        if self.scan_count == 0:
            raise BagError(f'{self.path}: topic {self.scan_topic} holds no messages')
        if odometry == 'auto':
            have = [t for t, ty in self.topics.items() if ty == ODOM_TYPE]
            odometry = odom_topic is not None or len(have) == 1
        if odometry:
            self.odom_topic = self._pick(odom_topic, ODOM_TYPE, 'Odometry', '--odom-topic')
        if transforms:
            self.tf_topics = [t for t in TF_TOPICS if self.topics.get(t) in TF_TYPES]
        self.estimate_topic = (ESTIMATE_TOPIC if self.topics.get(ESTIMATE_TOPIC) == ESTIMATE_TYPE
                               else None)

    def _pick(self, topic: Optional[str], msgtype: str, short: str, option: str) -> str:
        have = sorted(t for t, ty in self.topics.items() if ty == msgtype)
        if topic is not None:
            if topic not in self.topics:
                raise BagError(f'{self.path}: no topic {topic}; {short} topics: '
                               f'{", ".join(have) or "none"}')
            if self.topics[topic] != msgtype:
                raise BagError(f'{self.path}: topic {topic} is {self.topics[topic]}, not '
                               f'{msgtype}; {short} topics: {", ".join(have) or "none"}')
            return topic
        if len(have) == 1:
            return have[0]
        if not have:
            listed = ', '.join(f'{t} ({ty})' for t, ty in sorted(self.topics.items()))
            raise BagError(f'{self.path}: no {msgtype} topic in the bag (topics: '
                           f'{listed or "none"})')
        raise BagError(f'{self.path}: {len(have)} {short} topics ({", ".join(have)}); choose '
                       f'one with {option}')

    # -- reading -------------------------------------------------------------------------------
    def records(self) -> Iterator:
        """
        Yield Scan, Odometry, Transform, PoseEstimate and Skipped records in recording order.

        Raises BagError when the bag cannot be read on (e.g. truncated), naming how far it got.
        """
        for _, _, out in self.messages():
            if isinstance(out, list):
                yield from out
            else:
                yield out

    def messages(self) -> Iterator[tuple]:
        """
        Yield ``(log_time, topic, record)`` per message, in recording order.

        ``log_time`` is the bag's receive time in seconds; ``record`` is a Scan, an Odometry,
        a list of Transform (one TFMessage), a PoseEstimate or a Skipped. BagError as for
        ``records``.
        """
        if self._reader is None:
            raise BagError(f'{self.path}: bag is not open')
        reader = self._reader
        wanted = [self.scan_topic] + ([self.odom_topic] if self.odom_topic else []) \
            + self.tf_topics + ([self.estimate_topic] if self.estimate_topic else [])
        conns = [c for c in reader.connections if c.topic in wanted]
        errors = _read_errors()
        seen = 0
        stream = reader.messages(connections=conns)
        while True:
            try:
                conn, log_ns, raw = next(stream)
            except StopIteration:
                return
            except errors as exc:
                what = ('ROS 1 bag index does not match its chunks'
                        if self.path.lower().endswith('.bag') and self.reindexed is None
                        else 'truncated or corrupt?')
                raise BagError(f'{self.path}: unreadable after {seen} message(s), {what} '
                               f'({_why(exc)})') from None
            seen += 1
            try:
                msg = reader.deserialize(raw, conn.msgtype)
                out = self._convert(conn.topic, msg)
            except errors as exc:
                out = Skipped(conn.topic, f'undecodable {conn.msgtype} ({_why(exc)})')
            yield 1e-9 * log_ns, conn.topic, out

    def _convert(self, topic: str, msg):
        if topic == self.scan_topic:
            return Scan(_stamp(msg.header), clean_frame(msg.header.frame_id),
                        float(msg.angle_min), float(msg.angle_increment), float(msg.range_min),
                        float(msg.range_max), np.array(msg.ranges, dtype=np.float32),
                        time_increment=float(msg.time_increment),
                        scan_time=float(msg.scan_time), angle_max=float(msg.angle_max),
                        intensities=len(msg.intensities))
        if topic == self.odom_topic:
            pose = msg.pose.pose
            return Odometry(_stamp(msg.header), clean_frame(msg.header.frame_id),
                            clean_frame(msg.child_frame_id), _vec(pose.position),
                            _quat(pose.orientation))
        if topic == self.estimate_topic:
            pose = msg.pose.pose
            return PoseEstimate(_stamp(msg.header), clean_frame(msg.header.frame_id),
                                np.array([float(pose.position.x), float(pose.position.y),
                                          checked_yaw(*_quat(pose.orientation))]),
                                planar_covariance(msg.pose.covariance))
        static = TF_TOPICS[topic]
        return [Transform(_stamp(t.header), clean_frame(t.header.frame_id),
                          clean_frame(t.child_frame_id), _vec(t.transform.translation),
                          _quat(t.transform.rotation), static) for t in msg.transforms]


MCAP_MAGIC = b'\x89MCAP0\r\n'
"""The bytes every MCAP file starts (and, when complete, ends) with."""


def _mcap_hint(p: pathlib.Path, exc: BaseException) -> str:
    """
    Return advice for an .mcap file that ends early (a recorder stopped mid-write), or ''.

    A file that does not even start with the MCAP magic is said to be no MCAP file instead.
    """
    text = str(exc).lower()
    files = [p] if p.suffix.lower() == '.mcap' else sorted(p.glob('*.mcap')) if p.is_dir() else []
    if not files or not ('magic' in text or 'end of file' in text or 'unexpected end' in text):
        return ''
    for f in files:
        try:
            with open(f, 'rb') as fh:
                head = fh.read(len(MCAP_MAGIC))
        except OSError:
            continue
        if not MCAP_MAGIC.startswith(head):    # (a file cut inside the magic is a cut one)
            return f'; {f.name} is not an MCAP file (it does not start with the MCAP magic bytes)'
    return ('; the .mcap file ends early, as one does when the recorder was killed: '
            "'mcap recover FILE -o FIXED.mcap' (the mcap command-line tool) keeps what it "
            'holds')


def _why(exc: BaseException) -> str:
    """Return a short, single-line description of an exception."""
    text = ' '.join(str(exc).split())
    if not text:
        text = ('a consistency check failed' if isinstance(exc, AssertionError)
                else 'no details')
    if len(text) > 160:
        text = text[:157] + '...'
    return f'{exc.__class__.__name__}: {text}'


def _index_why(exc: BaseException) -> str:
    """Say in a few words why rosbags rejected a ROS 1 bag (its index, mostly)."""
    text = ' '.join(str(exc).split())
    if isinstance(exc, AssertionError) or not text:
        return 'malformed index records'
    if 'not indexed' in text:
        return 'no index: the recording was not closed'
    damaged = re.fullmatch(r'Bag index looks damaged: \((.*),\)', text)
    if damaged:                               # rosbags puts the reason's repr in parentheses
        text = 'index records unreadable: ' + damaged.group(1).strip('\'"')
    if len(text) > 120:
        text = text[:117] + '...'
    return text


class BagWriter:
    """
    Write records to a new rosbag2 (sqlite3 or mcap) with the ROS 2 Jazzy message types.

    Use as a context manager; ``write(topic, record, ...)`` takes Scan, Odometry or a list of
    Transform. /tf_static is offered transient-local, as tf2's static broadcaster does.
    """

    def __init__(self, path: str, storage: str = 'sqlite3'):
        _need_rosbags()
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.typesys import get_typestore, Stores
        plugins = {'sqlite3': StoragePlugin.SQLITE3, 'mcap': StoragePlugin.MCAP}
        if storage not in plugins:
            raise ValueError(f'storage must be sqlite3 or mcap, got {storage!r}')
        self.store = get_typestore(Stores.ROS2_JAZZY)
        self._writer = Writer(path, version=8, storage_plugin=plugins[storage])
        self._conns = {}

    def __enter__(self) -> 'BagWriter':
        """Create the bag folder and storage file."""
        self._writer.open()
        return self

    def __exit__(self, *exc) -> bool:
        """Write metadata.yaml and close."""
        self._writer.close()
        return False

    def _conn(self, topic: str, msgtype: str):
        if topic not in self._conns:
            from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness,
                                            QosReliability, QosTime)
            durability = (QosDurability.TRANSIENT_LOCAL if topic == '/tf_static'
                          else QosDurability.VOLATILE)
            zero = QosTime(0, 0)
            qos = Qos(QosHistory.KEEP_LAST, 1 if topic == '/tf_static' else 10,
                      QosReliability.RELIABLE, durability, zero, zero, QosLiveliness.AUTOMATIC,
                      zero, False)
            self._conns[topic] = self._writer.add_connection(
                topic, msgtype, typestore=self.store, offered_qos_profiles=[qos])
        return self._conns[topic]

    def _header(self, stamp: float, frame: str):
        t = self.store.types
        sec = int(np.floor(stamp))
        nsec = int(round((stamp - sec) * 1e9))
        if nsec >= 1_000_000_000:
            sec, nsec = sec + 1, nsec - 1_000_000_000
        return t['std_msgs/msg/Header'](t['builtin_interfaces/msg/Time'](sec, nsec), frame)

    def _pose_parts(self, translation, rotation):
        t = self.store.types
        return (t['geometry_msgs/msg/Vector3'](*map(float, translation)),
                t['geometry_msgs/msg/Quaternion'](*map(float, rotation)))

    def write(self, topic: str, record, log_time: float) -> None:
        """Write one record on ``topic`` with receive time ``log_time`` (seconds)."""
        t = self.store.types
        if isinstance(record, Scan):
            msgtype = SCAN_TYPE
            msg = t[SCAN_TYPE](self._header(record.stamp, record.frame_id),
                               record.angle_min, record.message_angle_max(),
                               record.angle_increment,
                               float(record.time_increment), float(record.scan_time),
                               record.range_min, record.range_max,
                               np.asarray(record.ranges, dtype=np.float32),
                               np.zeros(0, dtype=np.float32))
        elif isinstance(record, PoseEstimate):
            msgtype = ESTIMATE_TYPE
            x, y, yaw = (float(v) for v in record.pose)
            pose = t['geometry_msgs/msg/Pose'](
                t['geometry_msgs/msg/Point'](x, y, 0.0),
                t['geometry_msgs/msg/Quaternion'](*map(float, quaternion_from_yaw(yaw))))
            msg = t[msgtype](self._header(record.stamp, record.frame_id),
                             t['geometry_msgs/msg/PoseWithCovariance'](
                                 pose, pose_covariance(record.covariance)))
        elif isinstance(record, Odometry):
            msgtype = ODOM_TYPE
            pos = t['geometry_msgs/msg/Point'](*map(float, record.translation))
            ori = t['geometry_msgs/msg/Quaternion'](*map(float, record.rotation))
            pose = t['geometry_msgs/msg/PoseWithCovariance'](
                t['geometry_msgs/msg/Pose'](pos, ori), np.zeros(36))
            zero = t['geometry_msgs/msg/Vector3'](0.0, 0.0, 0.0)
            twist = t['geometry_msgs/msg/TwistWithCovariance'](
                t['geometry_msgs/msg/Twist'](zero, zero), np.zeros(36))
            msg = t[ODOM_TYPE](self._header(record.stamp, record.frame_id),
                               record.child_frame_id, pose, twist)
        else:
            msgtype = TF_TYPES[0]
            items = []
            for tr in record:
                trans, rot = self._pose_parts(tr.translation, tr.rotation)
                items.append(t['geometry_msgs/msg/TransformStamped'](
                    self._header(tr.stamp, tr.parent), tr.child,
                    t['geometry_msgs/msg/Transform'](trans, rot)))
            msg = t[msgtype](items)
        conn = self._conn(topic, msgtype)
        self._writer.write(conn, int(round(log_time * 1e9)),
                           self.store.serialize_cdr(msg, msgtype))
