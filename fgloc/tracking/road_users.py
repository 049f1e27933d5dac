"""Which tracks are motor vehicles.

The lanes fgloc registers tracks to are where motor vehicles drive. Other road users the radar
tracks do not drive there: cyclists ride at the lane's edge or on a bicycle lane beside it,
pedestrians walk on sidewalks and crosswalks. Registered to the nearest lane centre they pull
the pose across the lane: simulated cyclists 1.4 m right of the lane centres, 4 per minute,
took the mean 2D error over the three synthetic layouts (seeds 1-3) from 0.114 to 0.179 m
(filter-sicp) and from 0.079 to 0.191 m (smoother-sicp); without their tracks 0.122 and
0.104 m (docs/experiments.md).

A cyclist's track is short and narrow where the radar saw enough of it; a motor vehicle's is
neither (cars are 3.5-5 m long and 1.6-2 m wide). A track counts as a motor vehicle unless the
shorter of its contour's median length and width (over its steps) is below
``min_vehicle_width``, or the longer is below ``min_vehicle_length`` while the shorter is
below ``wide_vehicle_width`` (:class:`fgloc.tracking.config.TrackingConfig`). A sparsely
seen cyclist keeps a contour near the car-sized prior and passes as a vehicle: the rule drops
what it can tell (79 % of the cyclists' tracked detections over the robustness settings with
cyclists) and few vehicles' tracks (5 of 1003 there, 0.04 % of their detections).

A pedestrian is rarely seen well enough to shrink its contour (on the example map's junctions
with 10 pedestrians per minute on its crosswalks and walkways, their kept tracks had the
prior's 4.4 x 1.9 m), but it walks: a track whose speed stays below ``walking_speed`` for 90 %
of its steps is not a motor vehicle either (static returns are not tracked: a vehicle waiting
at a stop line leaves no track there, its track is its moving part).
"""

from __future__ import annotations

import numpy as np

from fgloc.tracking.config import TrackingConfig
from fgloc.tracks import Track, V, contour_length_width


def is_motor_vehicle(track: Track, cfg: TrackingConfig) -> bool:
    """Whether ``track``'s contour (median length and width over its steps, m) has a shorter
    side of at least ``cfg.min_vehicle_width`` and either a longer one of at least
    ``cfg.min_vehicle_length`` or a shorter one of at least ``cfg.wide_vehicle_width``, and
    its speed (90th percentile of |v| over its steps, m/s) reaches ``cfg.walking_speed``. The
    footprint's sides, whichever axis the tracker took for the heading (a car whose contour
    came out turned by 90 deg, 2.7 m long and 3.2 m wide, is a car); and a wide one is a
    vehicle however short (a car seen end-on, 2.9 m long and 2.5 m wide)."""
    if np.quantile(np.abs(track.states[:, V]), 0.9) < cfg.walking_speed:
        return False
    length, width = contour_length_width(track.states)
    short, long = sorted((float(np.median(length)), float(np.median(width))))
    return short >= cfg.min_vehicle_width and (long >= cfg.min_vehicle_length
                                               or short >= cfg.wide_vehicle_width)


def split_road_users(tracks: list[Track], cfg: TrackingConfig) -> tuple[list[Track], list[Track]]:
    """The motor vehicles' tracks and the others (:func:`is_motor_vehicle`), each in input
    order."""
    vehicle = [is_motor_vehicle(tr, cfg) for tr in tracks]
    return ([tr for tr, v in zip(tracks, vehicle) if v],
            [tr for tr, v in zip(tracks, vehicle) if not v])
