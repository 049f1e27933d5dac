"""Deprecated alias of :mod:`fgloc.evaluation.pose` (moved there in issue 23);
removed in the next release."""

from fgloc._deprecated import moved
from fgloc.evaluation import pose as _new

__getattr__ = moved(__name__, _new)
