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
"""

from __future__ import annotations

import struct
import zlib
from typing import Any, NamedTuple

__all__ = ["Message", "chunk_records", "stream_reader"]

_HEAD = struct.Struct("<BQ")  # opcode, record length
_MESSAGE = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_OP_MESSAGE = 0x05  # mcap.opcode.Opcode.MESSAGE
_OP_READ_BY_MCAP = {0x03: "Schema", 0x04: "Channel"}


class Message(NamedTuple):
    """A message of a chunk: the fields of ``mcap.records.Message`` the reader reads."""

    channel_id: int
    log_time: int
    data: bytes


def _uncompressed(chunk: Any) -> bytes:
    """The chunk's records as ``mcap.stream_reader.get_chunk_data_stream`` has them, CRC checked."""
    from mcap.exceptions import UnsupportedCompressionError
    from mcap.stream_reader import CRCValidationError, lz4, zstandard

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

    from mcap import records
    from mcap.data_stream import ReadDataStream

    stream = ReadDataStream(BytesIO(raw))
    try:
        rec = getattr(records, kind).read(stream)
    except Exception:  # noqa: BLE001 - read past the record: mcap reads the chunk
        return None
    return rec if stream.count == len(raw) else None


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
            rec = _read_whole(_OP_READ_BY_MCAP[op], data[body:pos])
            if rec is None:
                return _by_mcap(chunk)
            out.append(rec)
        # any other record in a chunk: skipped, as mcap skips it
    return out


def stream_reader(f: Any, size_limit: int) -> Any:
    """``mcap``'s StreamReader over ``f`` (CRCs validated, chunks emitted whole, records up to
    ``size_limit`` bytes) that reads a well-formed message index without parsing its entries:
    ``MessageIndex.read`` reads exactly its bytes then, or fails at the end of the file, as
    this does (a malformed one is read entry by entry, as ``mcap`` reads it). Its records
    are not returned (nothing here uses them); an ``mcap`` without the private hook this
    uses is used as it is."""
    from mcap.exceptions import EndOfFile
    from mcap.opcode import Opcode
    from mcap.stream_reader import StreamReader

    index = int(Opcode.MESSAGE_INDEX)

    class Reader(StreamReader):
        def _read_record(self, opcode: int, length: int) -> Any:
            if opcode != index:
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

    cls = Reader if callable(getattr(StreamReader, "_read_record", None)) else StreamReader
    reader = cls(f, validate_crcs=True, record_size_limit=size_limit, emit_chunks=True)
    if cls is Reader and not hasattr(reader, "_stream"):
        reader = StreamReader(f, validate_crcs=True, record_size_limit=size_limit, emit_chunks=True)
    return reader
