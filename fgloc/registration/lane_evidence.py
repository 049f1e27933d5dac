"""The joint's evidence for a lane model of two-way streets: how closely the tracks' centres
follow the lane lines.

The modes of :mod:`fgloc.registration.modes` compare fits by the per-track costs of their
*detections* about the lane lines. A detection lies on the vehicle's visible outline, a metre
or more beside the line its vehicle drives on (on the Lanelet2 example map's junction 5 the
mean cost per detection is that of a 1 m distance at the true pose), so those costs blur the
1-3 m between the two lane models of :mod:`fgloc.map.lane_models`: there the keep-right and
the centre-line fits tied within 1 % of their costs in 4 of 6 runs, and the least-cost one
was up to 0.66 m off.

The joint fits the track *centres* to the lines. At its final pose each track's frames have a
mean across-line residual about the track's own offset, the pose correction that fits the
offsets best taken off first (:func:`fgloc.registration.joint.frame_residuals`, the residuals
of the joint's noise levels); :func:`fgloc.registration.joint.track_misfit` sums their
robust costs per track. A track's constant offset from its line costs nothing (a driver off
the line); a change of it along the track does, and neither the track's offset nor the pose
takes it up: a track that keeps to the right half of a two-way street and turns out of it
wanders across the centre line as it goes, a track on the centre line across the right-half
line. On junction 5 (8 runs with both models: four kinds of traffic, seeds 1-2) the frame
level (:class:`~fgloc.registration.joint.NoiseLevels`) of the traffic's model was 0.10-0.33 m,
of the other 0.33-0.68 m, higher in every run.

The misfits of the fits of two models are compared track by track like the modes' costs
(:func:`fgloc.registration.modes.separation_z`, each model by its best fit, the least summed
misfit): a model beaten by ``mode_z`` standard errors is ruled out.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from fgloc.registration.modes import separation_z


def decided_lane_model(misfits: Sequence[tuple[str, np.ndarray]], z_min: float
                       ) -> tuple[str | None, dict[str, object]]:
    """The lane model the joint's fits decide, and the evidence.

    ``misfits``: (lane model, per-track misfit (n_tracks,), the same tracks for every fit)
    per fit. Each model counts with its best fit (least summed misfit). Returns the best
    model when it beats every other one by at least ``z_min`` standard errors
    (:func:`~fgloc.registration.modes.separation_z`), else None (one model only, or not
    decisive), and a summary: per model its best summed misfit (``misfit``) and the standard
    errors by which the best model beats it (``z``, 0 for the best; the selection among tied
    modes weighs them, :meth:`fgloc.registration.modes.ModeChoice.selected_by`), and the
    decision (``decided``).
    """
    best: dict[str, np.ndarray] = {}
    for model, m in misfits:
        if model not in best or float(m.sum()) < float(best[model].sum()):
            best[model] = np.asarray(m, dtype=float)
    top = min(best, key=lambda k: float(best[k].sum()), default=None)
    z = {k: 0.0 if k == top else separation_z(v, best[top]) for k, v in best.items()}
    decided = top if len(z) > 1 and min(v for k, v in z.items() if k != top) >= z_min else None
    return decided, {"misfit": {k: float(v.sum()) for k, v in best.items()}, "z": z,
                     "decided": decided}
