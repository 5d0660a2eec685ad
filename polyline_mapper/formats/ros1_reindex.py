"""
ROS 1 bags whose index is missing or damaged, read by scanning their chunks as rosbag reindex does.

A ROS 1 bag (format 2.0, http://wiki.ros.org/Bags/Format/2.0) is the line ``#ROSBAG V2.0``
followed by records ``<header_len><header><data_len><data>``; a header is a list of
``<len>name=value`` fields and its ``op`` field gives the record type: the bag header (0x03,
padded to 4 KiB, holding the position of the index), chunks (0x05, their data optionally
compressed with bz2 or lz4, holding connection records 0x07 and message data 0x02), after each
chunk its index data (0x04), and at the end the index: every connection (0x07) and a chunk
info (0x06) per chunk. A recording cut off by a crash has no index (``index_pos`` 0 or past the
end of the file) and may end inside a chunk; the ROS 1 recorder writes an uncompressed chunk's
messages straight to the file and its sizes only when the chunk is closed, so the last chunk of
a crashed recording declares no data.

``ReindexedReader`` is a ``rosbags.rosbag1.Reader`` whose ``open`` walks the records from the
bag header on instead of reading the index: it collects the connections and an index entry per
message, and stops cleanly at a truncated or unreadable tail, keeping the complete messages of
an uncompressed chunk cut short. Everything else (message order, topics, counts, decoding) is
rosbags' own, so the records are the ones the intact bag gives, up to the damage.
"""

from bz2 import decompress as bz2_decompress
from collections import defaultdict
import os
import struct
from typing import NamedTuple

from lz4.frame import decompress as lz4_decompress
from rosbags.interfaces import (Connection, ConnectionExtRosbag1, MessageDefinition,
                                MessageDefinitionFormat)
from rosbags.rosbag1 import Reader
from rosbags.rosbag1.reader import Chunk, ChunkInfo, decompressors, IndexData, normalize
from rosbags.typesys.msg import normalize_msgtype

MAGIC = b'#ROSBAG V2.0\n'
OP_MSGDATA, OP_BAGHEADER, OP_IDXDATA, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION = 2, 3, 4, 5, 6, 7
MAX_HEADER = 1 << 24
"""Largest record header accepted (bytes): connection headers hold message definitions."""
MAX_OPEN_CHUNK = 1 << 28
"""Most bytes read of an uncompressed chunk whose end is unknown (the recorder's are < 1 MiB)."""
DECOMPRESS = {'none': bytes, 'bz2': bz2_decompress, 'lz4': lz4_decompress}
CHUNK_OP = b'\x04\x00\x00\x00op=\x05'
"""The op field of a chunk header, length first: what a resync after damage looks for."""
_U32 = struct.Struct('<L')
_TIME = struct.Struct('<LL')


class ReindexError(ValueError):
    """A file in which no message could be found without the index, with the reason."""


class NotABagError(ReindexError):
    """A file that is not a ROS 1 bag of format 2.0 (or one this reader cannot read at all)."""


class ScanReport(NamedTuple):
    """What the scan found: counts, and where and why it stopped when before the end."""

    messages: int
    chunks: int
    connections: int
    end: str
    """'clean' (every record read), 'cut' (the file ends inside a record) or 'damaged'."""
    stop: int
    """Byte where the scan stopped (the file size when clean)."""
    size: int
    """File size, bytes."""
    orphans: int
    """Messages dropped because no connection record names their connection."""
    skipped: tuple = ()
    """(byte, length) of each unreadable stretch the scan skipped to the next chunk."""
    unclosed: bool = False
    """Whether a chunk declares no size: the recorder never closed it (it crashed)."""

    def describe(self) -> str:
        """Return a one-line summary for a warning."""
        text = (f'{self.messages} message(s) on {self.connections} connection(s) in '
                f'{self.chunks} chunk(s)')
        if self.skipped:
            text += f'; skipped {len(self.skipped)} unreadable stretch(es) (' + ', '.join(
                f'{n} bytes at byte {at}' for at, n in self.skipped[:3]) + \
                (', ...' if len(self.skipped) > 3 else '') + ')'
        if self.unclosed and self.end != 'cut':
            text += '; the last chunk was never closed (truncated recording)'
        if self.end == 'cut':
            text += (f'; the file ends inside a record at byte {self.stop} of {self.size} '
                     '(truncated recording): what follows the last complete message is lost')
        elif self.end == 'damaged':
            text += (f'; unreadable records from byte {self.stop} of {self.size} to the end '
                     f'({self.size - self.stop} bytes, no chunk in them)')
        if self.orphans:
            text += f'; {self.orphans} message(s) without a connection record dropped'
        return text


class _Stop(Exception):
    """
    The scan cannot go on at byte ``pos``: ``end`` is 'cut' or 'damaged'.

    ``resume``: where the next record starts when that is known all the same (a damaged chunk
    whose size was readable).
    """

    def __init__(self, end: str, pos: int, why: str, resume: int = None):
        super().__init__(why)
        self.end = end
        self.pos = pos
        self.resume = resume


def _fields(buf, pos: int, length: int, where: int) -> dict:
    """Parse the header fields in ``buf[pos:pos + length]``; name (str) -> value (bytes)."""
    out = {}
    end = pos + length
    while pos < end:
        if pos + 4 > end:
            raise _Stop('damaged', where, 'a header field length overruns the header')
        (n,) = _U32.unpack_from(buf, pos)
        pos += 4
        if n > end - pos:
            raise _Stop('damaged', where, 'a header field overruns the header')
        name, sep, value = bytes(buf[pos:pos + n]).partition(b'=')
        if not sep:
            raise _Stop('damaged', where, 'a header field without "="')
        try:
            out[name.decode('ascii')] = value
        except UnicodeDecodeError:
            raise _Stop('damaged', where, 'a header field name is not text') from None
        pos += n
    return out


def _op(fields: dict, where: int) -> int:
    op = fields.get('op', b'')
    if len(op) != 1:
        raise _Stop('damaged', where, 'a record without an op field')
    return op[0]


def _u32(fields: dict, name: str, where: int) -> int:
    value = fields.get(name, b'')
    if len(value) != 4:
        raise _Stop('damaged', where, f'field {name} missing or not 4 bytes')
    return _U32.unpack(value)[0]


def _text(fields: dict, name: str, where: int) -> str:
    try:
        return fields[name].decode()
    except (KeyError, UnicodeDecodeError):
        raise _Stop('damaged', where, f'field {name} missing or not text') from None


def _record(buf, pos: int, end: int) -> tuple:
    """
    Read the record at ``pos`` of ``buf`` (which ends at ``end``).

    Returns ``(fields, data_pos, data_len)``; raises _Stop 'cut' when the record runs past
    ``end`` (its data may be only partly there: data_len is then what it declares) and
    'damaged' when it is not a record.
    """
    if end - pos < 4:
        raise _Stop('cut', pos, 'the header length is cut')
    (hlen,) = _U32.unpack_from(buf, pos)
    if hlen < 5 or hlen > MAX_HEADER:            # an op field needs 4 + len('op=') + 1 bytes
        raise _Stop('damaged', pos, f'header length {hlen}')
    if pos + 8 + hlen > end:
        raise _Stop('cut', pos, 'the header is cut')
    fields = _fields(buf, pos + 4, hlen, pos)
    (dlen,) = _U32.unpack_from(buf, pos + 4 + hlen)
    return fields, pos + 8 + hlen, dlen


class ReindexedReader(Reader):
    """
    rosbags' ROS 1 reader, opened by scanning the records instead of reading the index.

    After ``open()``, ``report`` (ScanReport) says what was found; ReindexError when the file
    is not a ROS 1 bag or holds no readable message.
    """

    def __init__(self, path):
        super().__init__(path)
        self.report = None
        self._unclosed = False

    def open(self) -> None:                     # noqa: A003 - rosbags' name
        """Open the file and rebuild the index in memory from its chunks."""
        self.bio = self.path.open('rb')
        try:
            self._scan()
        except BaseException:
            self.close()
            raise

    def _scan(self) -> None:
        fh = self.bio
        size = os.fstat(fh.fileno()).st_size
        if fh.read(len(MAGIC)) != MAGIC:
            raise NotABagError('not a ROS 1 bag of format 2.0 (no "#ROSBAG V2.0" line)')
        conns, entries, infos, chunks = {}, defaultdict(list), [], {}
        state = (size, conns, entries, infos, chunks)
        end, stop, skipped = 'clean', size, []
        try:
            fields, data_pos, dlen = self._header(len(MAGIC), size)
        except _Stop as stopped:
            raise NotABagError(f'the bag header is unreadable ({stopped})') from None
        if _op(fields, len(MAGIC)) != OP_BAGHEADER:
            raise NotABagError('the first record is not a bag header')
        if fields.get('encryptor'):
            raise NotABagError('encrypted bags are not supported')
        pos = data_pos + dlen
        while pos < size:
            try:
                pos = self._step(pos, state)
            except _Stop as stopped:
                # Damaged (or seemingly cut) records: go on at the next readable chunk, if any.
                nxt = stopped.resume or self._resync(stopped.pos + 1, size)
                if nxt is None:
                    end, stop = stopped.end, stopped.pos
                    break
                skipped.append((stopped.pos, nxt - stopped.pos))
                pos = nxt
        indexes = {c: sorted(entries.pop(c, [])) for c in sorted(conns)}
        self.connections = [Connection(*conns[c][0:5], len(indexes[c]), *conns[c][6:])
                            for c in sorted(conns)]
        self.indexes = indexes
        self.chunk_infos = infos
        self.chunks = chunks
        count = sum(len(v) for v in indexes.values())
        orphans = sum(len(v) for v in entries.values())
        self.report = ScanReport(count, len(infos), len(conns), end, stop, size, orphans,
                                 tuple(skipped), self._unclosed)
        if count == 0:
            where = '' if end == 'clean' else f', unreadable from byte {stop} of {size} on'
            raise ReindexError(f'no readable message ({len(infos)} chunk(s) with messages, '
                               f'{len(conns)} connection(s){where})')

    def _step(self, pos: int, state: tuple) -> int:
        """Read the record at byte ``pos`` (a chunk: index it); return where the next starts."""
        size, conns, entries, infos, chunks = state
        fields, data_pos, dlen = self._header(pos, size)
        op = _op(fields, pos)
        if op == OP_CHUNK:
            return self._chunk(pos, fields, data_pos, dlen, *state)
        if data_pos + dlen > size:
            raise _Stop('cut', pos, 'the record data is cut')
        if op == OP_CONNECTION:
            self._connection(fields, self._read(data_pos, dlen), pos, conns)
        elif op not in (OP_IDXDATA, OP_CHUNK_INFO):
            raise _Stop('damaged', pos, f'record type {op} outside a chunk')
        return data_pos + dlen

    def _resync(self, start: int, size: int):
        """Return the byte of the next readable chunk header at or after ``start``, or None."""
        fh, block, at = self.bio, 1 << 20, start
        while at < size:
            fh.seek(at)
            buf = fh.read(block + len(CHUNK_OP))
            k = buf.find(CHUNK_OP)
            while k >= 0:
                field = at + k                  # the op field, its length first
                for head in range(field - 4, max(start, field - 4 - 256) - 1, -1):
                    try:
                        fields, data_pos, _ = self._header(head, size)
                        if (data_pos - 4 >= field + len(CHUNK_OP)
                                and _op(fields, head) == OP_CHUNK
                                and _text(fields, 'compression', head) in DECOMPRESS):
                            return head
                    except _Stop:
                        pass
                k = buf.find(CHUNK_OP, k + 1)
            at += block
        return None

    def _header(self, pos: int, size: int) -> tuple:
        """Read the header of the record at byte ``pos``: (fields, data_pos, data_len)."""
        fh = self.bio
        fh.seek(pos)
        head = fh.read(4)
        if len(head) < 4:
            raise _Stop('cut', pos, 'the header length is cut')
        (hlen,) = _U32.unpack(head)
        if hlen < 5 or hlen > MAX_HEADER:        # an op field takes 4 + len('op=') + 1 bytes
            raise _Stop('damaged', pos, f'header length {hlen}')
        if pos + 8 + hlen > size:
            raise _Stop('cut', pos, 'the header is cut')
        rest = fh.read(hlen + 4)
        return _fields(rest, 0, hlen, pos), pos + 8 + hlen, _U32.unpack_from(rest, hlen)[0]

    def _read(self, pos: int, n: int) -> bytes:
        self.bio.seek(pos)
        return self.bio.read(n)

    def _connection(self, fields: dict, data: bytes, where: int, conns: dict) -> None:
        """Register a connection record (header: conn, topic; data: type, md5sum, ...)."""
        cid = _u32(fields, 'conn', where)
        if cid in conns:
            return
        topic = _text(fields, 'topic', where)
        info = _fields(data, 0, len(data), where)
        latching = info.get('latching', b'').decode(errors='replace')
        callerid = info['callerid'].decode(errors='replace') if 'callerid' in info else None
        conns[cid] = Connection(
            cid, normalize(topic) if topic else topic,
            normalize_msgtype(_text(info, 'type', where)),
            MessageDefinition(MessageDefinitionFormat.MSG,
                              _text(info, 'message_definition', where)),
            _text(info, 'md5sum', where), 0,
            ConnectionExtRosbag1(callerid, int(latching) if latching.isdigit() else None),
            self)

    def _chunk(self, pos, fields, data_pos, dlen, size, conns, entries, infos, chunks) -> int:
        """
        Index the records of the chunk at byte ``pos``; return where the next record starts.

        An uncompressed chunk that runs past the end of the file, or declares no data (the
        sizes the recorder writes only when it closes the chunk), is open-ended: its records
        are read up to the first that is not a message or connection or is incomplete, and
        the scan goes on from there. Messages found before a damaged record are kept.
        """
        compression = _text(fields, 'compression', pos)
        if compression not in DECOMPRESS:
            raise _Stop('damaged', pos, f'chunk compression {compression!r} is not supported')
        declared = _u32(fields, 'size', pos)
        cut = data_pos + dlen > size
        open_ended = compression == 'none' and (cut or (dlen == 0 and declared == 0))
        if cut and not open_ended:
            raise _Stop('cut', pos, 'a compressed chunk is cut')
        if open_ended:
            raw = self._read(data_pos, min(size - data_pos, MAX_OPEN_CHUNK))
        elif dlen == 0:
            raw = b''                               # a compressed chunk never written
        else:
            try:
                raw = DECOMPRESS[compression](self._read(data_pos, dlen))
            except Exception:                       # noqa: B902 - whatever the codec raises
                raise _Stop('damaged', pos, 'the chunk does not decompress',
                            data_pos + dlen) from None
            if declared and len(raw) != declared:
                raise _Stop('damaged', pos, 'the chunk size does not match its data',
                            data_pos + dlen)
        found, failure, at, n = [], None, 0, len(raw)
        while at < n:
            try:
                rec, rdata, rlen = _record(raw, at, n)
                op = _op(rec, pos)
                if op not in (OP_MSGDATA, OP_CONNECTION):
                    if open_ended:
                        break                       # the chunk's records end here
                    raise _Stop('damaged', pos, f'record type {op} inside a chunk')
                if rdata + rlen > n:
                    raise _Stop('cut', pos, 'a record of the chunk is cut')
                if op == OP_CONNECTION:
                    self._connection(rec, bytes(raw[rdata:rdata + rlen]), pos, conns)
                else:
                    stamp = rec.get('time', b'')
                    if len(stamp) != 8:
                        raise _Stop('damaged', pos, 'a message without an 8-byte time')
                    sec, nsec = _TIME.unpack(stamp)
                    found.append((_u32(rec, 'conn', pos), IndexData(sec * 10**9 + nsec, pos, at)))
            except _Stop as stopped:
                failure = stopped
                break
            at = rdata + rlen
        if found:
            counts = defaultdict(int)
            for cid, entry in found:
                entries[cid].append(entry)
                counts[cid] += 1
            stamps = [entry.time for _, entry in found]
            infos.append(ChunkInfo(pos, min(stamps), max(stamps) + 1, dict(counts)))
            chunks[pos] = (Chunk(at, data_pos, decompressors['none']) if open_ended
                           else Chunk(dlen, data_pos, decompressors[compression]))
        if dlen == 0 and declared == 0:
            self._unclosed = True
        if not open_ended:
            if failure is not None:
                raise _Stop('damaged', pos, f'in the chunk: {failure}', data_pos + dlen)
            return data_pos + dlen
        if cut:
            raise _Stop('cut', data_pos + at, 'the chunk is cut')
        return data_pos + at                        # the outer scan says what follows
