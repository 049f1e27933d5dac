"""The smoothers' extent rows take Huber weights (issue 20): one frame whose extreme detection
is not the vehicle's end must not shift a whole smoothed track. Known truth: the robustness
matrix's "combined" setting, T-junction seed 4, where a 5.6 m van hid the rear half of a
receding 9.4 m truck for a frame (the truck's returns then reached 6 m from its front only)."""

from __future__ import annotations

import dataclasses

import numpy as np

from bench.robustness import sim_config
from fgloc.config import Config
from fgloc.evaluation.tracking import evaluate_tracks
from fgloc.pipeline import track
from fgloc.sim import simulate_detailed
from fgloc.smoothing.run import smooth_tracks
from fgloc.tracks import contour_length_width


def test_a_truck_hidden_in_part_for_a_frame_keeps_its_smoothed_centre() -> None:
    scn = simulate_detailed("tjunction", 4, 60.0, config=sim_config("combined")).scenario
    cfg = Config()
    run = track(scn, cfg, oracle_pose=True)
    kw = {"sensor_pose": scn.truth.sensor_pose, "hfov_deg": scn.sensor.hfov_deg,
          "max_range": scn.sensor.max_range}
    truth = {v.id: v for v in scn.truth.tracks}
    rows = [r for r in evaluate_tracks(run.tracks, scn.truth, **kw).rows
            if r.truth_id is not None and truth[r.truth_id].length > 9.0 and r.n >= 200]
    # two trucks followed for 200 steps and more (a third, 86-182 m out for 159 steps, is
    # far and sparse: 0.65 m either way)
    assert len(rows) == 2
    ids = {r.track_id for r in rows}
    trucks = dataclasses.replace(run.tracks, tracks=[t for t in run.tracks.tracks if t.id in ids])
    batch = smooth_tracks(scn, trucks, run.T_placement, "batch", cfg)
    by_id = {r.track_id: r for r in evaluate_tracks(batch, scn.truth, **kw).rows}
    for tr in batch.tracks:
        row, true = by_id[tr.id], truth[by_id[tr.id].truth_id]
        length = float(np.median(contour_length_width(tr.states)[0]))
        print(f"track {tr.id}: truck {true.length:.2f} m, smoothed length {length:.2f} m, "
              f"centre RMS {row.centre_rms:.3f} m, IoU {row.iou:.3f}")
        # without the weights: the truck of 9.38 m came out 10.51 m long, its centre
        # 0.5-1.8 m ahead of the truth, centre RMS 0.741 m, IoU 0.79
        assert row.centre_rms < 0.45
        assert abs(length - true.length) < 0.8
        assert row.iou > 0.85
