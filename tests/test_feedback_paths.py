"""The GNSS feedback logic is written once: a vehicle's estimates and scores are identical
through the per-vehicle ``EstimatorFeedback.update`` (a batch of one; or the scalar filters of a
bank the batched kernels do not support) and through the engine's batched bank, alone or in a
batch with other vehicles.  And a bank that cannot batch says so."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import ag_uav
from ag_uav.engine.missions import simulate_many
from ag_uav.navigation.estimation import BatchEstimatorFeedback, EstimatorFeedback
from ag_uav.seeds import seed_sequences


def _cfg(seed: int = 0, **over):
    base = {"sim.max_time_s": 12.0, "gps.preset": "standalone", "gps.multipath_prob": 0.05,
            "estimator.name": "pca-mckf", "estimator.shadow": ["kf", "mckf", "pca-kf"],
            "seed": seed, "estimator.nav": "ideal-attitude"}  # the position-filter bank's paths
    base.update(over)
    cfg = ag_uav.load_config(None, base)
    cfg.log.enabled = False
    return cfg


def _fb(cfg, cls=EstimatorFeedback):
    ss = seed_sequences(cfg.seed)
    return cls(cfg, ss["gps"], ss["altimeter"], ss["imu"])


class _OneByOne:
    """Flies an EstimatorFeedback through its per-vehicle ``update`` (the engine batches
    nothing that is not an EstimatorFeedback)."""

    def __init__(self, inner: EstimatorFeedback) -> None:
        self.inner = inner

    @classmethod
    def batch(cls, feedbacks, n_max):
        return None

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def __setattr__(self, name, value):
        if name == "inner":
            object.__setattr__(self, name, value)
        else:
            setattr(self.inner, name, value)


class _Scalar(EstimatorFeedback):
    """The scalar-filter path (what a bank with an unbatchable filter flies on)."""

    @classmethod
    def batch(cls, feedbacks, n_max):
        return None


def _scores(res):
    return {k: {kk: vv for kk, vv in v.items() if kk != "update_us"}
            for k, v in res.summary["estimators"].items()}


@pytest.fixture(scope="module")
def batched():
    return ag_uav.simulate(_cfg())


def test_per_vehicle_paths_equal_the_batched_bank(batched):
    fb = _fb(_cfg())
    alone = ag_uav.simulate(_cfg(), feedback=_OneByOne(fb))
    assert fb._solo  # flown as a batch of one
    scalar = ag_uav.simulate(_cfg(), feedback=_fb(_cfg(), _Scalar))
    for res in (alone, scalar):
        np.testing.assert_array_equal(res.p_fb, batched.p_fb)
        np.testing.assert_array_equal(res.p_true, batched.p_true)
        assert _scores(res) == _scores(batched)
    assert batched.summary["estimators"]["mckf"]["updates"] > 50


def test_a_vehicle_is_the_same_in_a_batch_of_three(batched):
    many = simulate_many([_cfg(2), _cfg(), _cfg(1)])
    np.testing.assert_array_equal(many[1].p_fb, batched.p_fb)
    assert _scores(many[1]) == _scores(batched)
    assert not np.array_equal(many[0].p_fb, batched.p_fb)


def test_a_bank_that_cannot_batch_says_why():
    fbs = [_fb(_cfg(**{"estimator.shadow": ["kf-bias"]})) for _ in range(2)]
    with pytest.warns(RuntimeWarning, match="no batched version of BiasAugmentedKF"):
        assert BatchEstimatorFeedback.try_batch(fbs, 100) is None
    for fb in fbs:
        assert "BiasAugmentedKF" in fb.batch_note
    ok = [_fb(_cfg())]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert BatchEstimatorFeedback.try_batch(ok, 100) is not None
    assert ok[0].batch_note is None
