"""Scoring against ground truth: the pose error (:mod:`fgloc.evaluation.pose`), the tracking
metrics (:mod:`fgloc.evaluation.tracking`) and the filter / smoother comparison on one scenario
(:mod:`fgloc.evaluation.trackers`). It sits above the pipeline (the comparison runs it); no
pipeline stage imports it. Import the submodules directly (they load scipy, the comparison the
pipeline).
"""
