"""Lane models of two-way streets mapped as one lanelet: where in the lanelet each direction
drives.

A real Lanelet2 map may draw a two-way street as one lanelet (``one_way = no``, 5-8 m wide; 60
of the 328 drivable lanelets of the Lanelet2 example map) and does not say where on it each
direction drives. Two models, 1-3 m apart on such a street (:func:`fgloc.scenario.lane_lines`):

* ``"keep-right"``: a two-way lanelet at least ``[map] two_way_min_width`` m wide holds one lane
  per direction, each on the centre of its right half (right-hand traffic);
* ``"centre"``: every two-way lanelet is driven on its centre line in both directions (what a
  generator that drives lanelet centre lines makes, and narrow residential streets).

``[map] two_way_lanes = "auto"`` gives every coarse mode in both models when the target holds a
two-way lanelet wide enough for them to differ, and the later stages choose between them on
the tracks' fit like between any other modes (:mod:`fgloc.registration.modes`); a map without
one has a single model and costs nothing extra.
"""

from __future__ import annotations

import math

from fgloc.config import MapConfig
from fgloc.scenario import TWO_WAY_MIN_WIDTH, Lanelet

KEEP_RIGHT = "keep-right"
CENTRE = "centre"
#: the lane models, in the order ``"auto"`` tries them
MODELS: tuple[str, ...] = (KEEP_RIGHT, CENTRE)


def min_width(model: str, keep_right_width: float = TWO_WAY_MIN_WIDTH) -> float:
    """The ``two_way_min_width`` (m) of :func:`fgloc.scenario.lane_lines` that gives ``model``:
    ``keep_right_width`` (the localization passes ``[map] two_way_min_width``) for
    "keep-right", infinity for "centre"."""
    if model not in MODELS:
        raise ValueError(f"unknown lane model {model!r}; expected one of {', '.join(MODELS)}")
    return keep_right_width if model == KEEP_RIGHT else math.inf


def other_model_note(model: str, reference: str) -> str:
    """``", <model> lanes"`` when ``model`` differs from ``reference`` (for warnings naming
    modes against the best one), else empty."""
    return "" if model == reference else f", {model} lanes"


def lane_models(lanelets: list[Lanelet], cfg: MapConfig) -> tuple[str, ...]:
    """The lane models to try on ``lanelets`` (those of the target cloud): ``[map]
    two_way_lanes`` when it names one, else ("auto") both when a two-way lanelet among them is
    at least ``two_way_min_width`` m wide, only "keep-right" (the same lanes as "centre") when
    none is."""
    if cfg.two_way_lanes != "auto":
        return (cfg.two_way_lanes,)
    if any(ll.keeps_right(cfg.two_way_min_width) for ll in lanelets):
        return MODELS
    return (KEEP_RIGHT,)
