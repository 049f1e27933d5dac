"""fgloc.pipeline.localize_many: the same poses as separate localize() calls, with shared stages
computed once and every result reporting the stage times a separate run would."""

from __future__ import annotations

import numpy as np
import pytest

from fgloc.config import Config
from fgloc.pipeline import METHODS, SharedStages, localize, localize_many
from fgloc.sim import simulate


def check_equal_to_separate_runs(methods: list[str], seed: int, duration: float) -> None:
    scn = simulate("tjunction", seed, duration=duration, vehicles=12)
    cfg = Config()
    stages = SharedStages(scn, cfg)
    many = localize_many(scn, methods, cfg, stages)
    assert list(many) == methods
    for m in methods:
        one = localize(scn, m, cfg)
        np.testing.assert_allclose(many[m].T_local, one.T_local, atol=1e-9, err_msg=m)
        assert many[m].method == m
        assert set(many[m].timings) == set(one.timings), (m, many[m].timings, one.timings)
    assert "tracking" not in many["icp"].timings
    # a second call with the same stages runs no shared stage again
    before = dict(stages.seconds)
    again = localize_many(scn, methods[::-1], cfg, stages)
    assert stages.seconds == before
    for m in methods:
        np.testing.assert_allclose(again[m].T_local, many[m].T_local, atol=1e-12)


def test_icp_and_filter_sicp_share_their_stages() -> None:
    check_equal_to_separate_runs(["icp", "filter-sicp"], 1, 10.0)    # resolved, 3 s a run


@pytest.mark.slow
def test_every_method_equals_its_separate_run() -> None:
    check_equal_to_separate_runs(sorted(METHODS), 4, 20.0)    # ambiguous: modes and valleys


def test_joint_on_smoothed_tracks_shares_the_smoothing_stage() -> None:
    """``[joint] smoother = "batch"``: the joint refines the batch smoother's tracks (a
    different pose than on the filter's), the same in localize() and localize_many(), which
    computes the smoothing once for smoother-sicp and joint and reports it in both."""
    import dataclasses

    from fgloc.progress import Timer
    from fgloc.registration.joint import joint_from_tracks

    scn = simulate("tjunction", 1, duration=10.0, vehicles=12)      # resolved, 4-6 s a run
    plain = Config()
    cfg = dataclasses.replace(plain, joint=dataclasses.replace(plain.joint, smoother="batch"))
    one = localize(scn, "joint", cfg)
    assert one.diagnostics["joint"]["smoother"] == "batch"
    assert "smoothing (batch)" in one.timings
    stages = SharedStages(scn, cfg)
    many = localize_many(scn, ["smoother-sicp", "joint"], cfg, stages)
    np.testing.assert_allclose(many["joint"].T_local, one.T_local, atol=1e-9)
    assert set(many["joint"].timings) == set(one.timings)
    assert sum(k.startswith("smoothed") for k in stages._cache) == 1
    tracks = stages.tracks()
    with pytest.raises(ValueError, match="smoothed"):      # other tracks than the filter's
        joint_from_tracks(scn, cfg, *stages.coarse(), tracks, Timer(),
                          smoothed=dataclasses.replace(tracks, tracks=tracks.tracks[1:]))
    on_filter = localize(scn, "joint", plain)
    assert "smoothing (batch)" not in on_filter.timings
    assert np.abs(on_filter.T_local[:2, 3] - one.T_local[:2, 3]).max() > 1e-6
