"""Turning a truncated or damaged run log into a finished, indexed MCAP (:func:`recover`)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from .rundata import mcap_path


def recover(in_path: str | Path, out_path: str | Path) -> Any:
    """Rewrite a truncated or damaged MCAP (or a run folder's) into a finished, indexed one.

    Every intact chunk survives (CRC-checked, read by
    :class:`~ag_uav.analysis.logscan.LogScan`); a damaged chunk and the partial chunk at a cut
    are lost.  Schemas, channels, metadata and attachments are copied; message order is kept.
    The output is written atomically.  Returns the scan's
    :class:`~ag_uav.analysis.logscan.ScanReport` (``messages`` kept, ``lost``, what was
    skipped).  An output equal to the input or a folder, a non-MCAP input, or a log with no
    intact message raise :class:`~ag_uav.analysis.logscan.LogError`.
    """
    from ..record.atomic import atomic_path
    from .logscan import LogError, LogScan

    src, out = mcap_path(in_path), Path(out_path)
    if out.is_dir():
        raise LogError(f"OUT = {out} is a folder; give the new file's name, e.g. "
                       f"{out / 'recovered.mcap'}")
    if out.exists() and os.path.samefile(out, src):
        raise LogError(f"OUT must differ from IN ({src}); the input is kept as it is")
    scan = LogScan(src)
    with atomic_path(out) as tmp:
        with open(tmp, "wb") as g:
            _copy_records(scan, g)
        if scan.report.messages == 0:
            tmp.unlink()
            why = scan.report.describe(counts=False)
            raise LogError(f"no intact message in {src}; nothing written"
                           + (f" ({why})" if why else ""))
    return scan.report


def _copy_records(scan: Any, g: Any) -> None:
    """Write what ``scan`` reads into a new MCAP on ``g`` (channels as their messages come)."""
    from mcap.records import Attachment, Message, Metadata
    from mcap.writer import CompressionType, Writer

    w = Writer(g, compression=CompressionType.ZSTD)
    w.start(profile="", library="ag_uav.recover")
    schema_map: dict[int, int] = {}
    channel_map: dict[int, int] = {}
    for rec in scan.records():
        if isinstance(rec, Message):
            cid = channel_map.get(rec.channel_id)
            if cid is None:
                ch = scan.channels[rec.channel_id]
                sch = scan.schemas.get(ch.schema_id)
                if sch is not None and sch.id not in schema_map:
                    schema_map[sch.id] = w.register_schema(sch.name, sch.encoding, sch.data)
                cid = channel_map[ch.id] = w.register_channel(
                    ch.topic, ch.message_encoding, schema_map.get(ch.schema_id, 0),
                    dict(ch.metadata))
            w.add_message(cid, rec.log_time, rec.data, rec.publish_time, rec.sequence)
        elif isinstance(rec, Metadata):
            w.add_metadata(rec.name, dict(rec.metadata))
        elif isinstance(rec, Attachment):
            w.add_attachment(rec.create_time, rec.log_time, rec.name, rec.media_type, rec.data)
    w.finish()
