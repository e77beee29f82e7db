"""An MCAP chunk's records, split out of its bytes at C speed (``traceio.reader``'s MCAP path).

``mcap``'s StreamReader reads a chunk's messages through a Python stream, field by field
(a read call and a ``struct.unpack`` each): four of the 50 CPU seconds of checking a capture
of a million datagrams (issue 17). :func:`chunk_records` gives what
``mcap.stream_reader.breakup_chunk(chunk, validate_crc=True)`` gives, in the same order, with
the same errors (an unsupported compression, a failed CRC), its messages as :class:`Message`
tuples with the fields the reader uses (a channel or schema record read by ``mcap``). A chunk
it does not take whole (a record longer than what is left of the chunk, a channel read past
its length: cut or crafted) is split by ``mcap`` itself, so an odd chunk reads exactly as
before. :func:`stream_reader` is ``mcap``'s
StreamReader but for the message index after each chunk (unused here), which it reads past
instead of parsing 16 bytes at a time: the same bytes consumed and the same errors.

A record whose bytes are all there (a chunk, a channel, a schema, a chunk index: in a chunk or
in the file) is read from them with ``struct`` (:func:`_parse`) when its fields fill it as
``mcap`` reads them, and by ``mcap`` itself from the same position otherwise (a record cut by
the end of the file, or odd): ``mcap`` reads such a record a field at a time, a Python call,
a read and a CRC update each -- most of reading a capture cut at each of its 20,000 bytes
(issue 38) and a tenth of checking a million datagrams.
"""

from __future__ import annotations

import struct
import zlib
from typing import Any, NamedTuple

from mcap import records
from mcap.exceptions import EndOfFile, UnsupportedCompressionError
from mcap.opcode import Opcode
from mcap.stream_reader import CRCValidationError, StreamReader, lz4, zstandard

__all__ = ["Message", "chunk_records", "stream_reader"]

_HEAD = struct.Struct("<BQ")  # opcode, record length
_MESSAGE = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_OP_MESSAGE = 0x05  # mcap.opcode.Opcode.MESSAGE
_OP_READ_BY_MCAP = {0x03: "Schema", 0x04: "Channel"}
#: the records :class:`stream_reader`'s reader reads whole when they are (schema, channel,
#: chunk, message index, chunk index)
_FAST = frozenset((0x03, 0x04, 0x06, 0x07, 0x08))


class Message(NamedTuple):
    """A message of a chunk: the fields of ``mcap.records.Message`` the reader reads."""

    channel_id: int
    log_time: int
    data: bytes


def _uncompressed(chunk: Any) -> bytes:
    """The chunk's records as ``mcap.stream_reader.get_chunk_data_stream`` has them, CRC checked."""
    if chunk.compression == "zstd":
        if zstandard is None:
            raise UnsupportedCompressionError("zstandard")
        data: bytes = zstandard.decompress(chunk.data, chunk.uncompressed_size)
    elif chunk.compression == "lz4":
        if lz4 is None:
            raise UnsupportedCompressionError("lz4")
        data = lz4.decompress(chunk.data)
    else:
        data = chunk.data
    if chunk.uncompressed_crc != 0:
        crc = zlib.crc32(data)
        if crc != chunk.uncompressed_crc:
            raise CRCValidationError(expected=chunk.uncompressed_crc, actual=crc, record=chunk)
    return data


def _by_mcap(chunk: Any) -> list[Any]:
    from mcap.records import Message as McapMessage
    from mcap.stream_reader import breakup_chunk

    return [Message(r.channel_id, r.log_time, r.data) if type(r) is McapMessage else r
            for r in breakup_chunk(chunk, validate_crc=True)]


def _read_whole(kind: str, raw: bytes) -> Any:
    """``mcap``'s record of ``kind`` read from ``raw``, when it reads all of ``raw`` and nothing
    more (as it then reads it in the chunk); else None."""
    from io import BytesIO

    from mcap.data_stream import ReadDataStream

    stream = ReadDataStream(BytesIO(raw))
    try:
        rec = getattr(records, kind).read(stream)
    except Exception:  # noqa: BLE001 - read past the record: mcap reads the chunk
        return None
    return rec if stream.count == len(raw) else None


class _Odd(Exception):
    """A record :func:`_parse` does not read as ``mcap`` would: ``mcap`` reads it."""


_U16, _U32, _U64 = struct.Struct("<H").unpack_from, struct.Struct("<I").unpack_from, struct.Struct("<Q").unpack_from
_CHUNK = struct.Struct("<QQQI")  # message start and end time, uncompressed size and CRC
_CHUNK_INDEX = struct.Struct("<QQQQ")  # message start and end time, chunk start offset and length
_OFFSET = struct.Struct("<HQ")  # a chunk index's channel id and its message index's offset


def _int(unpack: Any, size: int, b: bytes, pos: int, end: int) -> tuple[int, int]:
    if pos + size > end:
        raise _Odd
    return unpack(b, pos)[0], pos + size  # type: ignore[no-any-return]


def _bytes(b: bytes, pos: int, end: int, size: int = 4) -> tuple[bytes, int]:
    n, pos = _int(_U32 if size == 4 else _U64, size, b, pos, end)
    if pos + n > end:
        raise _Odd
    return b[pos:pos + n], pos + n


def _string(b: bytes, pos: int, end: int) -> tuple[str, int]:
    raw, pos = _bytes(b, pos, end)
    return str(raw, "utf-8"), pos  # mcap's read_prefixed_string: its UnicodeDecodeError is _parse's too


def _map(b: bytes, pos: int, end: int) -> tuple[dict[str, str], int]:
    n, pos = _int(_U32, 4, b, pos, end)
    stop = pos + n
    if stop > end:
        raise _Odd
    out: dict[str, str] = {}
    while pos < stop:  # mcap reads pairs while short of the map's end: one across it is odd
        key, pos = _string(b, pos, stop)
        out[key], pos = _string(b, pos, stop)
    return out, pos


def _parse(op: int, b: bytes, pos: int, end: int) -> tuple[Any, int]:
    """The record of opcode ``op`` in ``b[pos:end]`` as ``mcap.records`` reads it from those
    bytes, and where it stops; :class:`_Odd` (or a decode error) where ``mcap`` would read past
    ``end`` or fail: then ``mcap`` reads it, so that an odd record reads exactly as before."""
    if op == 0x06:  # Chunk
        if pos + 28 > end:
            raise _Odd
        start, stop, size, crc = _CHUNK.unpack_from(b, pos)
        compression, pos = _string(b, pos + 28, end)
        data, pos = _bytes(b, pos, end, 8)
        return records.Chunk(compression=compression, data=data, message_end_time=stop, message_start_time=start,
                             uncompressed_crc=crc, uncompressed_size=size), pos
    if op == 0x04:  # Channel
        channel, pos = _int(_U16, 2, b, pos, end)
        schema, pos = _int(_U16, 2, b, pos, end)
        topic, pos = _string(b, pos, end)
        encoding, pos = _string(b, pos, end)
        metadata, pos = _map(b, pos, end)
        return records.Channel(id=channel, topic=topic, message_encoding=encoding, metadata=metadata,
                               schema_id=schema), pos
    if op == 0x03:  # Schema
        schema, pos = _int(_U16, 2, b, pos, end)
        name, pos = _string(b, pos, end)
        encoding, pos = _string(b, pos, end)
        data, pos = _bytes(b, pos, end)
        return records.Schema(id=schema, name=name, encoding=encoding, data=data), pos
    if op == 0x08:  # ChunkIndex
        if pos + 36 > end:
            raise _Odd
        start, stop, offset, length = _CHUNK_INDEX.unpack_from(b, pos)
        n = _U32(b, pos + 32)[0]
        pos += 36
        if n % 10 or pos + n > end:  # an entry across the offsets' end: mcap reads on
            raise _Odd
        offsets = {}
        for k in range(pos, pos + n, 10):
            channel, at = _OFFSET.unpack_from(b, k)
            offsets[channel] = at
        index_length, pos = _int(_U64, 8, b, pos + n, end)
        compression, pos = _string(b, pos, end)
        compressed, pos = _int(_U64, 8, b, pos, end)
        uncompressed, pos = _int(_U64, 8, b, pos, end)
        return records.ChunkIndex(chunk_length=length, chunk_start_offset=offset, compression=compression,
                                  compressed_size=compressed, message_end_time=stop,
                                  message_index_length=index_length, message_index_offsets=offsets,
                                  message_start_time=start, uncompressed_size=uncompressed), pos
    raise _Odd


def _whole(op: int, b: bytes, pos: int, end: int) -> Any:
    """The record :func:`_parse` reads in ``b[pos:end]`` when it fills it exactly, else None."""
    try:
        rec, stop = _parse(op, b, pos, end)
    except (_Odd, UnicodeDecodeError):
        return None
    return rec if stop == end else None


def chunk_records(chunk: Any) -> list[Any]:
    """The records of ``chunk`` (an ``mcap.records.Chunk``), as ``mcap``'s ``breakup_chunk``
    with CRCs validated gives them, its messages as :class:`Message`."""
    data = _uncompressed(chunk)
    out: list[Any] = []
    head, message = _HEAD.unpack_from, _MESSAGE.unpack_from
    pos, end = 0, len(data)
    while pos < end:
        if end - pos < 9:
            return _by_mcap(chunk)
        op, length = head(data, pos)
        body = pos + 9
        pos = body + length
        if pos > end:
            return _by_mcap(chunk)
        if op == _OP_MESSAGE:
            if length < 22:
                return _by_mcap(chunk)
            channel, _seq, log_time, _published = message(data, body)
            out.append(Message(channel, log_time, data[body + 22:pos]))
        elif op in _OP_READ_BY_MCAP:  # a channel or schema: mcap's, when it takes the record whole
            rec = _whole(op, data, body, pos)
            if rec is None:
                rec = _read_whole(_OP_READ_BY_MCAP[op], data[body:pos])
            if rec is None:
                return _by_mcap(chunk)
            out.append(rec)
        # any other record in a chunk: skipped, as mcap skips it
    return out


_OP_INDEX = int(Opcode.MESSAGE_INDEX)


class _Reader(StreamReader):
    """:func:`stream_reader`'s reader (one class for every file read, not one made per file)."""

    def _read_record(self, opcode: int, length: int) -> Any:
        if opcode in _FAST:
            s = self._stream
            count, crc, raw = s._count, s._crc, s._stream
            body = raw.read(length)
            if len(body) == length:  # the whole record is there
                if opcode == _OP_INDEX:
                    entries = _U32(body, 2)[0] if length >= 6 else -1
                    rec, whole = None, entries == length - 6 and entries % 16 == 0
                else:
                    try:
                        rec, stop = _parse(opcode, body, 0, length)
                        whole = True  # mcap reads what is left of the record as padding
                    except (_Odd, UnicodeDecodeError):
                        rec, whole = None, False
                if whole:  # the bytes mcap's reading consumes, counted and CRC'd as it does
                    s._count = count + length
                    if crc is not None:
                        s._crc = zlib.crc32(body, crc)
                    return rec
            raw.seek(-len(body), 1)  # mcap reads it, from where it starts
        if opcode != _OP_INDEX:
            return super()._read_record(opcode, length)
        s = self._stream
        s.read2()  # channel id
        entries = s.read4()
        if entries == length - 6 and entries % 16 == 0:
            if entries and len(s.read(entries)) < entries:
                raise EndOfFile()
            return None
        end = s.count + entries
        while s.count < end:
            s.read8()
            s.read8()
        return None


def stream_reader(f: Any, size_limit: int) -> Any:
    """``mcap``'s StreamReader over ``f`` (CRCs validated, chunks emitted whole, records up to
    ``size_limit`` bytes) that reads a well-formed message index without parsing its entries:
    ``MessageIndex.read`` reads exactly its bytes then, or fails at the end of the file, as
    this does (a malformed one is read entry by entry, as ``mcap`` reads it). Its records
    are not returned (nothing here uses them); an ``mcap`` without the private hook this
    uses is used as it is."""
    seekable = getattr(f, "seekable", lambda: False)()
    cls = _Reader if seekable and callable(getattr(StreamReader, "_read_record", None)) else StreamReader
    reader = cls(f, validate_crcs=True, record_size_limit=size_limit, emit_chunks=True)
    if cls is _Reader and not hasattr(reader, "_stream"):
        reader = StreamReader(f, validate_crcs=True, record_size_limit=size_limit, emit_chunks=True)
    return reader
