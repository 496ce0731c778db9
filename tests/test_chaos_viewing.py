"""Chaos: viewing is bounded.  ``show`` of a finished log decodes no message (counts, times and
sizes come from the summary section and the message indexes, and match a full scan exactly);
``plot`` decodes only the last grid and scene of each topic and a decimated time series.  The
bounds on a 38 ha job's log (seconds, not minutes) are measured in docs/guides/foxglove.md."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mcap_protobuf.decoder import DecoderFactory

import ag_uav
from ag_uav.analysis import viewing
from ag_uav.jobs.run import fly


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """A 12 s flight with the dose model: three /dose grids, scenes, estimators."""
    cfg = ag_uav.load_config(None, {"sim.max_time_s": 12.0, "log.render": False})
    _, d = fly(cfg, out_root=tmp_path_factory.mktemp("v"), run_id="r")
    return d


@pytest.fixture
def decoded(monkeypatch) -> list[str]:
    """The schema names of the messages decoded from now on."""
    names: list[str] = []
    orig = DecoderFactory.decoder_for

    def counting(self, encoding, schema):
        dec = orig(self, encoding, schema)

        def wrapped(data):
            names.append(schema.name)
            return dec(data)
        return wrapped

    monkeypatch.setattr(DecoderFactory, "decoder_for", counting)
    return names


def test_show_reads_the_summary_section_without_decoding(run_dir, decoded):
    full = viewing.read_run(run_dir, images=False)
    assert decoded and full.channels["/dose"]["count"] >= 3
    decoded.clear()
    fast = viewing.read_summary(run_dir)
    assert fast is not None and decoded == []
    assert fast.channels == full.channels  # counts, first/last times and bytes, per topic
    assert (fast.t_start, fast.t_end) == (full.t_start, full.t_end)
    assert fast.metadata == full.metadata and fast.attachments == full.attachments
    text = viewing.show(run_dir)
    assert decoded == [] and "finished, indexed" in text and "/dose" in text


def test_plot_decodes_the_last_grid_and_a_decimated_series(run_dir, decoded):
    whole = viewing.read_run(run_dir, images=False)
    n_state = len(whole.series["/drone/state"].t)
    decoded.clear()
    d = viewing.read_run(run_dir, images=False, max_points=40)
    assert decoded.count("foxglove.Grid") == 1  # of the log's three or more
    assert decoded.count("foxglove.SceneUpdate") == len(d.scenes)
    t = d.series["/drone/state"].t
    assert 40 <= len(t) < 80 and n_state > 2 * len(t)
    stride = round(np.median(np.diff(t)) / np.median(np.diff(whole.series["/drone/state"].t)))
    np.testing.assert_array_equal(t, whole.series["/drone/state"].t[::stride][:len(t)])
    assert d.channels == whole.channels  # the counts stay whole
    grid = d.grids["/dose"]
    assert grid.timestamp.seconds + grid.timestamp.nanos * 1e-9 == pytest.approx(
        whole.channels["/dose"]["t1"])
    paths = viewing.plot(d, run_dir / "plots")
    assert any(p.name == "dose.png" for p in paths)
