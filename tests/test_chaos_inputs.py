"""Chaos: inputs that must not escape or mislead.  Run ids that are paths, an origin that would
move a georeferenced field's plan, a KMZ zip bomb and oversized field files, empty or out-of-
envelope experiment axes, and a spray-settings search that would recommend what ``fly``
refuses.  Each case ends in one line and exit 2, or in a correct result."""

from __future__ import annotations

from pathlib import Path

import pytest

from ag_uav.cli import main
from ag_uav.config import ConfigError
from ag_uav.jobs.outdir import check_run_id
from ag_uav.jobs.run import fly

ROOT = Path(__file__).resolve().parents[1]
KML = "{http://www.opengis.net/kml/2.2}"


def _one_line_exit2(capsys, argv: list[str], *words: str) -> str:
    """``ag-uav argv`` exits 2 with one stderr line holding every word; returns the line."""
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    for w in words:
        assert w in err, (w, err)
    return err


# ---------------------------------------------------------------------------- run ids are names
@pytest.mark.parametrize("rid", ["../../escaped", "/tmp/abs-run", ".", "..", "", "a/b", "a\\b",
                                 "x\x00y", "x" * 256])
def test_run_id_that_is_a_path_is_refused(rid, tmp_path, capsys):
    out = tmp_path / "runs" / "rid"
    _one_line_exit2(capsys, ["fly", "--out", str(out), "--run-id", rid, "--no-log", "-q"],
                    "--run-id", "folder name")
    assert not out.exists() and not (tmp_path / "escaped").exists()
    with pytest.raises(ConfigError, match="--run-id"):  # the library refuses it too
        fly(None, out_root=out, run_id=rid)  # type: ignore[arg-type]
    assert not out.exists()


@pytest.mark.parametrize("rid", ["run-1", "2026_a.b", "feld-Ost", "..x", "a..b"])
def test_run_id_names_are_accepted(rid):
    assert check_run_id(rid) == rid
