"""Chaos: broken logs and full disks.  Every case ends in one line, no traceback.

Logs: a synthetic run through the real writer (RunLog, several chunks) for the damage cases,
and real short flights for the full-disk cases.  The per-chunk message counts the assertions
use come from the mcap library's own readers on the intact file, not from ag_uav's scanner.
Full disks are small tmpfs mounts (skipped, with the reason, where the runner may not mount).
"""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk
from PIL import Image

from ag_uav.analysis import viewing
from ag_uav.cli import main
from ag_uav.record.atomic import atomic_path, atomic_write_text
from ag_uav.record.runlog import RunLog
from ag_uav.record.synthetic import synthetic_run

ROOT = Path(__file__).resolve().parents[1]


def _jpeg(k: int) -> bytes:
    img = np.zeros((24, 32, 3), np.uint8)
    img[:, : (k * 3) % 32] = (200, 40, 40)
    buf = io.BytesIO()
    Image.fromarray(img).save(buf, format="JPEG", quality=70)
    return buf.getvalue()


@pytest.fixture(scope="module")
def log(tmp_path_factory) -> Path:
    """A 10 s synthetic run with camera frames: a dozen chunks."""
    d = tmp_path_factory.mktemp("chaos-run")
    n = [0]
    with RunLog(d / "run.mcap", channels="full", metadata={"seed": 1}, config_toml="a = 1\n",
                rates={"camera": 2.0}) as lg:
        def on_tick(t, p, q):
            if lg.want_frame(t):
                n[0] += 1
                lg.frame(t, "chase", _jpeg(n[0]), 32, 24, 60.0)
        synthetic_run(lg, 10.0, on_tick=on_tick)
        lg.summary({"rmse_m": 0.5})
    return d / "run.mcap"


def _chunks(path: Path) -> list[tuple[int, int, list[tuple]]]:
    """(start, end, messages) of each chunk, in file order, from the library's readers."""
    with open(path, "rb") as f:
        s = make_reader(f).get_summary()
        topic = {c.id: c.topic for c in s.channels.values()}
        out = []
        for ci in sorted(s.chunk_indexes, key=lambda c: c.chunk_start_offset):
            f.seek(ci.chunk_start_offset)
            chunk = next(StreamReader(f, skip_magic=True, emit_chunks=True).records)
            assert isinstance(chunk, Chunk)
            msgs = [(topic[m.channel_id], m.log_time, bytes(m.data))
                    for m in breakup_chunk(chunk, validate_crc=True) if isinstance(m, Message)]
            out.append((ci.chunk_start_offset, ci.chunk_start_offset + ci.chunk_length, msgs))
    return out


def _messages(path: Path) -> Counter:
    with open(path, "rb") as f:
        return Counter((c.topic, m.log_time, bytes(m.data))
                       for _, c, m in make_reader(f).iter_messages())


def _damaged(src: Path, dst: Path, at: int, n: int = 16) -> Path:
    b = bytearray(src.read_bytes())
    for i in range(at, at + n):
        b[i] ^= 0xA5
    dst.write_bytes(bytes(b))
    return dst


def _cli(capsys, *args: str) -> tuple[int, str, str]:
    rc = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return rc, out, err


#: what a first run on an empty kernel cache says before its work (a test may be the first of
#: its worker process to fly)
FIRST_RUN_NOTICES = ("compiling the log's encoders", "compiling kernels: first run only",
                     "compiled the kernels in")


def _one_line(err: str) -> str:
    """The one error line (the pre-flight notice of a mission cut by sim.max_time_s and the
    first run's compile notices aside)."""
    lines = [ln for ln in err.strip().splitlines() if "the plan needs at least" not in ln
             and not ln.startswith(FIRST_RUN_NOTICES)]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def _leftovers(folder: Path) -> list[str]:
    """0-byte files and temporary files under ``folder``."""
    return sorted(str(p) for p in folder.rglob("*") if p.is_file()
                  and (p.stat().st_size == 0 or ".tmp" in p.name))


# ------------------------------------------------------------------------ not a log at all
@pytest.fixture(scope="module")
def junk(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("junk")
    (d / "empty.mcap").write_bytes(b"")
    (d / "random.mcap").write_bytes(np.random.default_rng(7).bytes(4096))
    (d / "text.mcap").write_text("not a log\n")
    (d / "magic.mcap").write_bytes(b"\x89MCAP0\r\n" + np.random.default_rng(8).bytes(4096))
    return {p.stem: p for p in d.iterdir()}


@pytest.mark.parametrize("kind", ["empty", "random", "text", "magic"])
@pytest.mark.parametrize("tool", ["show", "plot", "video", "recover"])
def test_a_file_that_is_not_mcap_is_refused(capsys, tmp_path, junk, kind, tool):
    args = {"show": [], "plot": ["-o", tmp_path / "plots"], "video": ["-o", tmp_path / "v.mp4"],
            "recover": [tmp_path / "out.mcap"]}[tool]
    rc, out, err = _cli(capsys, tool, junk[kind], *args)
    line = _one_line(err)
    assert rc == 2 and out == ""
    assert str(junk[kind]) in line
    magic = "no intact message" if tool == "recover" else "nothing readable"
    assert {"empty": "empty file", "magic": magic}.get(kind, "not an MCAP file") in line
    assert list(tmp_path.iterdir()) == []  # nothing written


def test_the_entry_point_prints_one_line_not_a_traceback(junk):
    r = subprocess.run([sys.executable, "-m", "ag_uav.cli", "show", str(junk["random"])],
                       capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.count("\n") == 1 and "not an MCAP file" in r.stderr


# ------------------------------------------------------------------------ damaged chunks
def test_recover_keeps_every_chunk_but_the_damaged_one(log, tmp_path):
    chunks = _chunks(log)
    total = _messages(log)
    assert len(chunks) >= 8 and sum(len(c[2]) for c in chunks) == sum(total.values())
    for k in (1, len(chunks) // 2, len(chunks) - 1):
        start, end, msgs = chunks[k]
        bad = _damaged(log, tmp_path / f"bad{k}.mcap", (start + end) // 2)
        rep = viewing.recover(bad, tmp_path / f"fixed{k}.mcap")
        assert rep.messages == sum(total.values()) - len(msgs) and rep.lost == len(msgs)
        assert [d.offset for d in rep.damage] == [start] and rep.damage[0].messages == len(msgs)
        assert f"skipped 1 of {len(chunks)} chunks" in rep.describe()
        assert _messages(tmp_path / f"fixed{k}.mcap") == total - Counter(msgs)


def test_recover_resyncs_after_a_damaged_record_header(log, tmp_path):
    """The chunk's length field itself is flipped: the summary's index finds the next one."""
    chunks = _chunks(log)
    start, _, msgs = chunks[3]
    bad = _damaged(log, tmp_path / "hdr.mcap", start + 1, 8)
    rep = viewing.recover(bad, tmp_path / "fixed.mcap")
    assert rep.lost == len(msgs) and "unreadable bytes" in rep.describe()
    assert _messages(tmp_path / "fixed.mcap") == _messages(log) - Counter(msgs)


def _announces_channels(chunk_start: int, path: Path) -> bool:
    with open(path, "rb") as f:
        f.seek(chunk_start)
        chunk = next(StreamReader(f, skip_magic=True, emit_chunks=True).records)
    return any(isinstance(r, Channel) for r in breakup_chunk(chunk))


def test_damage_and_cut_without_a_summary(log, tmp_path):
    """No footer, a flipped length field: the next chunk is found by its CRC alone."""
    chunks = _chunks(log)
    k = next(i for i in range(2, len(chunks)) if not _announces_channels(chunks[i][0], log))
    cut = chunks[-2][1] + 5  # a few bytes into what follows chunk n-2
    raw = bytearray(log.read_bytes()[:cut])
    start, _, msgs = chunks[k]
    for i in range(start + 1, start + 9):
        raw[i] ^= 0x5A
    (tmp_path / "x.mcap").write_bytes(bytes(raw))
    rep = viewing.recover(tmp_path / "x.mcap", tmp_path / "fixed.mcap")
    want = Counter(m for i, c in enumerate(chunks[:-1]) if i != k for m in c[2])
    assert not rep.indexed and rep.lost is None and rep.cut_at is not None
    assert _messages(tmp_path / "fixed.mcap") == want
    assert rep.messages == sum(want.values())


def test_channels_announced_in_a_lost_chunk_are_counted(log, tmp_path):
    """Without a summary, messages on a channel announced only in the lost chunk are lost
    too, and said so."""
    chunks = _chunks(log)
    k = next(i for i in range(1, len(chunks)) if _announces_channels(chunks[i][0], log))
    start, end, msgs = chunks[k]
    raw = bytearray(log.read_bytes()[:chunks[-1][1]])  # every chunk, no summary
    for i in range((start + end) // 2, (start + end) // 2 + 16):
        raw[i] ^= 0xA5
    (tmp_path / "x.mcap").write_bytes(bytes(raw))
    rep = viewing.recover(tmp_path / "x.mcap", tmp_path / "fixed.mcap")
    total = sum(len(c[2]) for c in chunks)
    assert rep.orphans > 0 and rep.messages + rep.orphans + len(msgs) == total
    assert rep.lost == rep.orphans + len(msgs) and "announced in lost chunks" in rep.describe()


@pytest.mark.parametrize("frac", [0.3, 0.55, 0.8, 0.999])
def test_truncated_log_keeps_every_complete_chunk(log, tmp_path, frac):
    size = log.stat().st_size
    cut = int(size * frac)
    (tmp_path / "cut.mcap").write_bytes(log.read_bytes()[:cut])
    rep = viewing.recover(tmp_path / "cut.mcap", tmp_path / "fixed.mcap")
    want = Counter(m for s, e, ms in _chunks(log) if e <= cut for m in ms)
    assert rep.messages == sum(want.values()) > 0
    assert _messages(tmp_path / "fixed.mcap") == want
    assert "cut short" in rep.describe() or rep.cut_at is None


def test_show_plot_video_work_on_a_damaged_log_and_say_what_was_skipped(capsys, log, tmp_path):
    chunks = _chunks(log)
    start, end, msgs = chunks[4]
    bad = _damaged(log, tmp_path / "run.mcap", (start + end) // 2)
    rc, out, err = _cli(capsys, "show", bad)
    assert rc == 0 and err == ""
    assert f"skipped 1 of {len(chunks)} chunks" in out and f"{len(msgs)} lost" in out
    state = next(ln for ln in out.splitlines() if ln.strip().startswith("/drone/state "))
    n_state = sum(1 for m in _messages(log) if m[0] == "/drone/state")
    assert int(state.split()[2]) == n_state - sum(1 for m in msgs if m[0] == "/drone/state")
    rc, out, err = _cli(capsys, "plot", bad, "-o", tmp_path / "plots")
    assert rc == 0 and "skipped 1 of" in _one_line(err)
    assert {Path(p).name for p in out.split()} >= {"map.png", "errors.png"}
    rc, out, err = _cli(capsys, "video", bad, "-o", tmp_path / "v.mp4", "--fps", "0")
    assert rc == 0 and "skipped 1 of" in _one_line(err)
    assert (tmp_path / "v.mp4").stat().st_size > 0
    assert _leftovers(tmp_path) == []


# ------------------------------------------------------------------------ one-line refusals
def test_video_and_recover_refusals_are_one_line(capsys, log, tmp_path):
    no_frames = tmp_path / "nf.mcap"
    with RunLog(no_frames, channels="light", metadata={}, config_toml="", layout=False) as lg:
        synthetic_run(lg, 2.0)
    cases = [
        (["video", no_frames, "-o", tmp_path / "a.mp4"], "no camera frames"),
        (["video", log, "-o", tmp_path / "a.mp4", "--camera", "nope"], "cameras: chase"),
        (["video", log, "-o", tmp_path / "a.mp4", "--fps", "-5"], "--fps = -5"),
        (["video", log, "-o", tmp_path / "a.mp4", "--fps", "nan"], "--fps = nan"),
        (["recover", log.parent, tmp_path], "is a folder"),
        (["recover", log, log], "must differ"),
        (["show", tmp_path / "missing.mcap"], "missing.mcap"),
    ]
    for args, words in cases:
        rc, out, err = _cli(capsys, *args)
        assert rc == 2 and words in _one_line(err), (args, err)
    assert not (tmp_path / "a.mp4").exists() and _leftovers(tmp_path) == []
    # a run folder is accepted as IN
    rc, _, err = _cli(capsys, "recover", log.parent, tmp_path / "r.mcap")
    assert rc == 0 and err.startswith(f"recovered {sum(_messages(log).values())} messages")


def test_plan_simplify_must_not_be_negative(capsys, tmp_path):
    rc, out, err = _cli(capsys, "plan", "-o", tmp_path / "p.plan", "--origin", "46.73,-117.0",
                        "--simplify", "-1")
    assert rc == 2 and "--simplify = -1" in _one_line(err) and "config error" in err
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------ atomic writes
def test_atomic_write_leaves_the_old_file_when_the_writer_fails(tmp_path):
    p = atomic_write_text(tmp_path / "a.json", "old")
    with pytest.raises(RuntimeError), atomic_path(p) as tmp:
        tmp.write_text("half")
        raise RuntimeError("writer died")
    assert p.read_text() == "old" and sorted(os.listdir(tmp_path)) == ["a.json"]


# ------------------------------------------------------------------------ full disks
@pytest.fixture
def tmpfs(tmp_path):
    """``mount(size)`` -> a fresh tmpfs of that size (unmounted after the test)."""
    mounted: list[Path] = []

    def mount(size: str, opts: str = "") -> Path:
        d = tmp_path / f"fs{len(mounted)}"
        d.mkdir()
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}{opts}", "tmpfs", str(d)],
                           capture_output=True, text=True)
        if r.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here ({r.stderr.strip() or r.returncode})")
        mounted.append(d)
        return d

    yield mount
    for d in mounted:
        subprocess.run(["umount", str(d)], capture_output=True)


def _fill(d: Path) -> None:
    """Fill the filesystem of ``d`` (a file of non-zero bytes up to ENOSPC)."""
    with open(d / "filler", "wb", buffering=0) as f:
        try:
            while True:
                f.write(b"x" * 1024)
        except OSError:
            pass


def test_plan_plot_recover_on_a_full_disk(capsys, tmpfs, log):
    d = tmpfs("64k")
    _fill(d)
    for args, target in (
        (["plan", "-o", d / "p.plan", "--origin", "46.73,-117.0"], d / "p.plan"),
        (["plot", log, "-o", d / "plots"], d / "plots" / "map.png"),
        (["recover", log, d / "r.mcap"], d / "r.mcap"),
        (["video", log, "-o", d / "v.mp4"], d / "v.mp4"),
    ):
        rc, _, err = _cli(capsys, *args)
        line = _one_line(err)
        assert rc == 1 and line.startswith(f"ag-uav: {target}: No space left on device"), line
        assert not target.exists()
    assert _leftovers(d) == []


def test_plan_into_a_read_only_folder(capsys, tmpfs):
    d = tmpfs("64k", ",ro")
    rc, _, err = _cli(capsys, "plan", "-o", d / "p.plan", "--origin", "46.73,-117.0")
    assert rc == 1 and _one_line(err) == f"ag-uav: {d / 'p.plan'}: Read-only file system"


def test_fly_on_a_full_disk_stops_with_one_line_and_a_readable_log(capsys, tmpfs):
    d = tmpfs("128k")   # the log's head (field, plan, map topics) fits; the first dose map not
    rc, _, err = _cli(capsys, "fly", "--no-render", "--set", "sim.max_time_s=5", "--out", d,
                      "--run-id", "r", "-q")
    log = d / "r" / "run.mcap"
    assert rc == 1
    assert _one_line(err).startswith(f"ag-uav: {log}: No space left on device")
    assert not (d / "r" / "summary.json").exists() and _leftovers(d) == []
    data = viewing.read_run(log, images=False)
    assert len(data.series["/drone/state"].t) > 5 and data.report.messages > 0


def test_fly_whose_summary_cannot_be_written_prints_it(capsys, tmpfs):
    d = tmpfs("64k")
    (d / "r").mkdir()
    _fill(d)
    rc, out, err = _cli(capsys, "fly", "--no-log", "--set", "sim.max_time_s=3", "--out", d,
                        "--run-id", "r", "-q")
    assert rc == 1
    assert _one_line(err) == f"ag-uav: {d / 'r' / 'summary.json'}: No space left on device"
    printed = json.loads(out[out.index("here it is:\n") + len("here it is:\n"):])
    assert printed["sim_time_s"] == pytest.approx(3.0, abs=0.05)
    assert "tracking_rmse_m" in printed and "run summary" in out
    assert sorted(os.listdir(d / "r")) == []
