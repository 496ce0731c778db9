"""The first run's second-core helper (ag_uav.engine.warm, started by ag_uav.jobs.run): when it
starts, that it flies the run's config on the true state in a process of its own, and that it
leaves nothing behind."""

from __future__ import annotations

import json

import pytest

from ag_uav.config import load_config
from ag_uav.engine import warm
from ag_uav.jobs.run import WARM_HELPER


@pytest.fixture
def can_help(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("AG_UAV_WARM", raising=False)
    monkeypatch.setattr(warm, "_cores", lambda: 2)
    monkeypatch.setattr(warm, "_ins_kernel_cached", lambda: False)


def test_helper_is_wanted_only_where_it_can_help(can_help, monkeypatch) -> None:
    cfg = load_config(None, {})
    assert warm.wanted(cfg)
    assert not warm.wanted(load_config(None, {"estimator.name": "true"}))
    assert not warm.wanted(load_config(None, {"estimator.nav": "ideal-attitude"}))
    monkeypatch.setenv("AG_UAV_WARM", "0")
    assert not warm.wanted(cfg)
    monkeypatch.delenv("AG_UAV_WARM")
    monkeypatch.setattr(warm, "_cores", lambda: 1)
    assert not warm.wanted(cfg)
    monkeypatch.setattr(warm, "_cores", lambda: 2)
    monkeypatch.setattr(warm, "_ins_kernel_cached", lambda: True)
    assert not warm.wanted(cfg)


def test_the_ins_kernel_cache_check_reads_numba_s_index() -> None:
    # the suite has flown the INS before or compiles it here: either way the answer is a bool
    # that matches the index file numba keeps for the kernel
    import os

    from estimators.ins.fusion import step_kernel

    index = step_kernel._cache._cache_file._index_path
    assert warm._ins_kernel_cached() is os.path.exists(index)


def test_helper_flies_the_config_on_the_true_state_and_leaves_nothing(can_help) -> None:
    cfg = load_config(None, {"seed": 3})
    w = warm.start(cfg, WARM_HELPER)
    assert w is not None
    assert w.proc.wait(timeout=600) == 0
    summary = json.loads((w.folder / "helper" / "summary.json").read_text())
    assert summary["feedback"] == "true" and summary["seed"] == 3
    assert summary["sim_time_s"] <= warm.FLY_S + 0.01
    assert (w.folder / warm.MCKF_DONE).exists()   # the MCKF update first, and said
    warm.stop(w)
    assert not w.folder.exists()


def test_stop_ends_a_helper_still_running(can_help) -> None:
    w = warm.start(load_config(None, {}), WARM_HELPER)
    assert w is not None
    warm.stop(w)  # at once: the helper is still importing
    assert w.proc.poll() is not None and not w.folder.exists()
    warm.stop(None)


def test_the_ins_compiled_first_is_the_kernel_a_run_calls(tmp_path) -> None:
    """:func:`warm.compile_ins` calls the INS's tick kernel with the argument types a run's bank
    passes: after a run, it adds no second specialisation (which the run would not use)."""
    from ag_uav.jobs.run import fly
    from estimators.ins.fusion import step_kernel

    cfg = load_config(None, {"sim.max_time_s": 0.2, "log.enabled": False})
    fly(cfg, out_root=tmp_path, run_id="r", progress=False, helper=False)
    sigs = list(step_kernel.signatures)
    warm.compile_ins()
    assert list(step_kernel.signatures) == sigs and len(sigs) == 1


def test_a_bad_field_is_said_before_any_compile(can_help, monkeypatch, tmp_path) -> None:
    """Where the run would compile the INS first, a field it cannot load is refused at once:
    no helper started, nothing compiled."""
    from ag_uav.config import ConfigError
    from ag_uav.jobs import run

    started: list[object] = []
    monkeypatch.setattr(warm, "start", lambda cfg, command: started.append(cfg))
    monkeypatch.setattr(warm, "compile_ins", lambda w=None: started.append("ins"))
    bow = tmp_path / "bow.geojson"
    bow.write_text(json.dumps({"type": "Polygon", "coordinates": [[[0, 0], [1, 1], [1, 0],
                                                                    [0, 1], [0, 0]]]}))
    cfg = load_config(None, {"mission.field": str(bow)})
    with pytest.raises(ConfigError, match="mission.field"):
        run.fly(cfg, out_root=tmp_path, run_id="r", progress=False)
    assert started == []


class _TypingOnly:
    """numba's nopython pipeline cut after type inference (a test oracle: what a kernel asks of
    the kernels it calls, without lowering it); built on first use."""

    @staticmethod
    def compiler() -> type:
        from numba.core.compiler import CompilerBase, DefaultPassBuilder
        from numba.core.compiler_machinery import PassManager
        from numba.core.typed_passes import NopythonTypeInference

        class TypingOnly(CompilerBase):
            def define_pipelines(self):  # type: ignore[no-untyped-def]
                pm = PassManager("typing only")
                for cls, desc in DefaultPassBuilder.define_nopython_pipeline(self.state).passes:
                    pm.add_pass(cls, desc)
                    if cls is NopythonTypeInference:
                        break
                pm.finalize()
                return [pm]

        return TypingOnly


def test_the_helpers_mckf_update_is_the_one_the_ins_calls() -> None:
    """The INS's tick kernel, typed, asks for the MCKF update with exactly the argument types
    that :func:`warm.compile_ins`'s helper half (:func:`warm.compile_mckf_row`) compiles: the
    run loads the helper's from the cache instead of compiling its own."""
    import numba

    from estimators.ins.fusion import step_kernel
    from estimators.mckf import mckf_update_row

    warm.compile_ins()
    asked: list[object] = []
    law_compile = type(mckf_update_row).compile
    mckf_update_row.compile = lambda sig: asked.append(sig) or law_compile(mckf_update_row, sig)
    try:
        typed = numba.njit(pipeline_class=_TypingOnly.compiler())(step_kernel.py_func)
        with pytest.raises(AttributeError):  # no lowering: no compile result
            typed.compile(step_kernel.signatures[0])
    finally:
        del mckf_update_row.compile   # the dispatcher's own again
    helper = tuple(mckf_update_row.typeof_pyval(a) for a in warm.mckf_row_args())
    assert set(asked) == {helper}


def test_the_run_waits_for_the_helpers_mckf_update_then_compiles(tmp_path) -> None:
    """``compile`` of the law waits for the helper's file, or for the helper's end, then
    compiles (a cache hit when the helper wrote it), once."""
    import subprocess
    import sys
    import threading
    import time

    class Law:
        def __init__(self) -> None:
            self.calls: list[tuple[object, float]] = []

        def compile(self, sig):  # type: ignore[no-untyped-def]
            self.calls.append((sig, time.monotonic()))

    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        law, w = Law(), warm.Warmer(sleeper, tmp_path)
        law.compile = warm._after_helper(w, law)  # type: ignore[method-assign]
        t0 = time.monotonic()
        threading.Timer(0.4, (tmp_path / warm.MCKF_DONE).touch).start()
        law.compile("sig")
        assert law.calls[0][0] == "sig" and law.calls[0][1] - t0 >= 0.4
        assert "compile" not in law.__dict__      # waits once only
    finally:
        sleeper.kill()
        sleeper.wait()
    law = Law()   # the helper has ended without the file: no wait
    law.compile = warm._after_helper(warm.Warmer(sleeper, tmp_path / "none"), law)  # type: ignore[method-assign]
    t0 = time.monotonic()
    law.compile("sig")
    assert law.calls and law.calls[0][1] - t0 < 0.2
