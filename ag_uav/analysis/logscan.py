"""Reading an MCAP log that may be cut short or damaged: record by record, chunk by chunk.

An MCAP file (https://mcap.dev/spec) is the magic ``\\x89MCAP0\\r\\n``, a Header, the data
section (Schema, Channel, Metadata and Attachment records and Chunks; each Chunk is followed by
its MessageIndex records, one per channel, listing the chunk's messages), DataEnd, the summary
section (Schemas, Channels, Statistics, Chunk/Metadata/Attachment indexes) and a Footer that
points at it, then the magic again.  Every top-level record is ``opcode (u8), length (u64),
body``; a Chunk carries the CRC-32 of its uncompressed records, an Attachment the CRC-32 of its
body.

:class:`LogScan` walks the top-level records in file order with the ``mcap`` library's record
readers (``StreamReader`` on each record, ``breakup_chunk`` with CRC validation on each chunk),
so a chunk whose bytes were flipped is skipped alone and the walk goes on with the next record;
its MessageIndex records (outside the chunk) say how many messages it held.  When the framing
itself is broken (an opcode or a length damaged), the walk resumes at the next record the
summary's indexes name, or, without a summary, at the next offset where a whole chunk parses
and passes its CRC.  A file cut short (a killed run) ends at the last complete record.
Schemas and channels come from the summary when there is one, so a message whose channel was
announced in a lost chunk is still readable.

    scan = LogScan(path)            # raises NotMcapError for an empty or non-MCAP file
    for rec in scan.records(): ...  # Schema, Channel, Metadata, Attachment, Message (intact)
    scan.report                     # ScanReport: chunks, skipped, messages kept / lost, cut
"""

from __future__ import annotations

import io
import mmap
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["LogScan", "ScanReport", "Damage", "NotMcapError", "LogError", "check_mcap"]

MAGIC = b"\x89MCAP0\r\n"
_HDR = struct.Struct("<BQ")  # opcode, record length
_FOOTER_LEN = 9 + 8 + 8 + 4  # Footer record: header, summary_start, summary_offset_start, crc
_CHUNK_MIN = 8 + 8 + 8 + 4 + 4 + 8  # Chunk body with an empty compression name and no data


class LogError(ValueError):
    """A log tool cannot do what was asked with this file (one line, no traceback)."""


class NotMcapError(LogError):
    """The file is empty or is not an MCAP file."""


def check_mcap(path: str | Path) -> int:
    """Raise :class:`NotMcapError` unless ``path`` starts with the MCAP magic; its size."""
    p = Path(path)
    size = p.stat().st_size
    if size == 0:
        raise NotMcapError(f"{p}: empty file, not an MCAP log")
    with open(p, "rb") as f:
        head = f.read(len(MAGIC))
    if head != MAGIC:
        raise NotMcapError(f"{p}: not an MCAP file (it does not start with the MCAP magic)")
    return size


@dataclass
class Damage:
    """Something skipped: where (byte offset), what, and the messages it held if known."""

    offset: int
    what: str
    messages: int | None = None


@dataclass
class ScanReport:
    """What a scan found and what it had to skip."""

    path: Path
    size: int
    indexed: bool = False  # a footer and a summary section were readable
    chunks: int = 0  # chunks seen (intact or not)
    messages: int = 0  # messages kept
    expected: int | None = None  # message count the summary's statistics give
    orphans: int = 0  # messages on a channel never announced (its chunk was lost)
    damage: list[Damage] = field(default_factory=list)
    cut_at: int | None = None  # the file ends inside the record that starts here

    @property
    def finished(self) -> bool:
        """A complete, indexed file (it may still hold damaged chunks)."""
        return self.indexed and self.cut_at is None

    @property
    def lost(self) -> int | None:
        """Messages lost: from the statistics if any, else those the indexes count (None when
        the file is cut or its framing was broken and no count is known)."""
        if self.expected is not None:
            return max(self.expected - self.messages, 0)
        known = [d.messages for d in self.damage]
        if self.cut_at is not None or any(m is None for m in known):
            return None
        return sum(m or 0 for m in known) + self.orphans

    @property
    def intact(self) -> bool:
        return not self.damage and self.cut_at is None and not self.orphans

    def describe(self, counts: bool = True) -> str:
        """One line: what was skipped, then (``counts``) the messages kept and lost; empty
        when nothing was skipped."""
        parts = []
        bad = [d for d in self.damage if d.what.startswith("chunk")]
        if bad:
            where = ", ".join(f"byte {d.offset}" for d in bad[:3]) + (", ..." if len(bad) > 3
                                                                      else "")
            parts.append(f"skipped {len(bad)} of {self.chunks} chunks ({bad[0].what[6:]}; at "
                         f"{where})")
        other = [d for d in self.damage if not d.what.startswith("chunk")]
        if other:
            parts.append("skipped " + ", ".join(f"{d.what} at byte {d.offset}"
                                                for d in other[:3]))
        if self.cut_at is not None:
            parts.append(f"the file ends inside a record at byte {self.cut_at} (cut short: "
                         "a killed run or a full disk?)")
        if self.orphans:
            parts.append(f"{self.orphans} messages on channels announced in lost chunks")
        if not parts or not counts:
            return "; ".join(parts)
        lost = self.lost
        tail = (f"{self.messages} messages kept, {lost} lost" if lost is not None
                else f"{self.messages} messages kept, the rest lost")
        return "; ".join(parts) + f"; {tail}"


def _why(e: BaseException) -> str:
    """Why a record was skipped, in a few words."""
    name = type(e).__name__
    if name == "CRCValidationError":
        return "CRC mismatch"
    if "decompress" in str(e).lower():
        return "damaged, does not decompress"
    return f"damaged, unreadable ({name})"


class LogScan:
    """A file-order walk over an MCAP log that skips what is damaged (see the module doc)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        size = check_mcap(self.path)
        self.report = ScanReport(self.path, size)
        self.schemas: dict[int, Any] = {}
        self.channels: dict[int, Any] = {}
        self._offsets: list[int] = []  # record starts the summary names (resync points)
        self._data_end = size

    # -------------------------------------------------------------- summary (optional)
    def _read_summary(self, mm: Any) -> None:
        """Footer and summary section, if they are readable: schemas, channels, statistics,
        the offsets of chunks, metadata and attachments, the end of the data section."""
        from mcap.records import Footer
        from mcap.stream_reader import StreamReader

        size = self.report.size
        if size < 2 * len(MAGIC) + _FOOTER_LEN or mm[size - len(MAGIC):] != MAGIC:
            return
        try:
            footer = next(StreamReader(io.BytesIO(mm[size - len(MAGIC) - _FOOTER_LEN:]),
                                       skip_magic=True).records)
            if not isinstance(footer, Footer) or not 0 < footer.summary_start < size:
                return
            summary = self._summary_records(mm, footer.summary_start)
        except Exception:  # noqa: BLE001 - a damaged summary: scan without it
            return
        self._data_end = footer.summary_start
        self.report.indexed = True
        self.schemas.update(summary["schemas"])
        self.channels.update(summary["channels"])
        self.report.expected = summary["count"]
        self._offsets = sorted(o for o in summary["offsets"] if 0 < o < footer.summary_start)

    def _summary_records(self, mm: Any, start: int) -> dict[str, Any]:
        from mcap.records import (
            AttachmentIndex,
            Channel,
            ChunkIndex,
            Footer,
            MetadataIndex,
            Schema,
            Statistics,
        )
        from mcap.stream_reader import StreamReader

        out: dict[str, Any] = {"schemas": {}, "channels": {}, "count": None, "offsets": []}
        reader = StreamReader(io.BytesIO(mm[start:]), skip_magic=True)
        for rec in reader.records:
            if isinstance(rec, Schema):
                out["schemas"][rec.id] = rec
            elif isinstance(rec, Channel):
                out["channels"][rec.id] = rec
            elif isinstance(rec, Statistics):
                out["count"] = rec.message_count
            elif isinstance(rec, ChunkIndex):
                out["offsets"].append(rec.chunk_start_offset)
            elif isinstance(rec, (MetadataIndex, AttachmentIndex)):
                out["offsets"].append(rec.offset)
            elif isinstance(rec, Footer):
                break
        return out

    # -------------------------------------------------------------- the walk
    def records(self) -> Iterator[Any]:
        """Intact Schema, Channel, Metadata, Attachment and Message records, in file order."""
        with open(self.path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
            self._read_summary(mm)
            yield from self._walk(mm)

    def _walk(self, mm: Any) -> Iterator[Any]:
        from mcap.opcode import Opcode
        from mcap.records import Channel, Chunk, Message, MessageIndex, Schema

        rep, end_data = self.report, self._data_end
        ops = {int(o) for o in Opcode}
        pos, bad_chunk = len(MAGIC), None
        while pos < end_data:
            op, length = _HDR.unpack_from(mm, pos) if pos + 9 <= end_data else (0, 0)
            end = pos + 9 + length
            if pos + 9 > end_data or op not in ops or end > end_data:
                nxt = self._resync(mm, pos)
                if nxt is None:
                    if not rep.indexed:
                        rep.cut_at = pos
                    else:
                        rep.damage.append(Damage(pos, f"{end_data - pos} unreadable bytes"))
                    return
                rep.damage.append(Damage(pos, f"{nxt - pos} unreadable bytes"))
                pos, bad_chunk = nxt, None
                continue
            if op in (Opcode.DATA_END, Opcode.FOOTER):
                return
            try:
                rec = self._parse(mm, pos, end, op)
            except Exception as e:  # noqa: BLE001 - a damaged record: skip it
                if op == Opcode.CHUNK:
                    rep.chunks += 1
                    bad_chunk = Damage(pos, f"chunk {_why(e)}", 0)
                    rep.damage.append(bad_chunk)
                else:
                    rep.damage.append(Damage(pos, f"{Opcode(op).name.lower()} record "
                                                  f"{_why(e)}"))
                pos = end
                continue
            start, pos = pos, end
            if isinstance(rec, MessageIndex):
                if bad_chunk is not None:
                    bad_chunk.messages = (bad_chunk.messages or 0) + len(rec.records)
                continue
            if not isinstance(rec, Chunk):
                bad_chunk = None
                yield from self._keep(rec)
                continue
            rep.chunks += 1
            try:
                inner = self._unpack(rec)
            except Exception as e:  # noqa: BLE001 - CRC mismatch or undecodable chunk
                bad_chunk = Damage(start, f"chunk {_why(e)}", 0)
                rep.damage.append(bad_chunk)
                continue
            bad_chunk = None
            for r in inner:
                if isinstance(r, (Message, Schema, Channel)):
                    yield from self._keep(r)

    @staticmethod
    def _parse(mm: Any, pos: int, end: int, op: int) -> Any:
        """One top-level record with the library's reader; an attachment's CRC is checked."""
        from mcap.opcode import Opcode
        from mcap.stream_reader import CRCValidationError, StreamReader

        rec = next(StreamReader(io.BytesIO(mm[pos:end]), skip_magic=True, emit_chunks=True,
                                record_size_limit=None).records)
        if op == Opcode.ATTACHMENT:  # its last 4 bytes: CRC-32 of the body before them
            (want,) = struct.unpack_from("<I", mm, end - 4)
            crc = zlib.crc32(mm[pos + 9:end - 4])
            if want != 0 and crc != want:
                raise CRCValidationError(want, crc, rec)
        return rec

    @staticmethod
    def _unpack(chunk: Any) -> list[Any]:
        from mcap.stream_reader import breakup_chunk

        return breakup_chunk(chunk, validate_crc=True)

    def _keep(self, rec: Any) -> Iterator[Any]:
        from mcap.records import Channel, Message, Schema

        if isinstance(rec, Schema):
            self.schemas.setdefault(rec.id, rec)
        elif isinstance(rec, Channel):
            self.channels.setdefault(rec.id, rec)
        elif isinstance(rec, Message):
            if rec.channel_id not in self.channels:
                self.report.orphans += 1
                return
            self.report.messages += 1
        yield rec

    def _resync(self, mm: Any, pos: int) -> int | None:
        """The next readable record start after ``pos``: from the summary's indexes, else the
        next offset where a whole chunk parses and passes its CRC; None if there is none."""
        if self.report.indexed:
            return next((o for o in self._offsets if o > pos), None)
        from mcap.opcode import Opcode

        end_data = self._data_end
        c = mm.find(b"\x06", pos + 1, end_data)
        while c != -1:
            if c + 9 <= end_data:
                _, length = _HDR.unpack_from(mm, c)
                if _CHUNK_MIN <= length <= end_data - c - 9:
                    try:
                        chunk = self._parse(mm, c, c + 9 + length, Opcode.CHUNK)
                        if chunk.uncompressed_crc != 0:  # a CRC is what makes it a match
                            self._unpack(chunk)
                            return c
                    except Exception:  # noqa: BLE001, S112 - not a chunk start: look further
                        pass
            c = mm.find(b"\x06", c + 1, end_data)
        return None
