"""GP-EOT tracking (UKF) of the vehicles a roadside radar sees, in the coarse frame C."""

from fgloc.labels import kappa_labels
from fgloc.tracking.config import TrackingConfig
from fgloc.tracking.tracker import Tracker, track_scenario

__all__ = ["TrackingConfig", "Tracker", "kappa_labels", "track_scenario"]
