"""The math of fgloc: motion, contour and measurement models and the GTSAM factors on them.

Depends only on numpy, scipy and gtsam; never imports :mod:`fgloc`.
"""
