"""Deprecated alias of :mod:`fgloc.registration.modes` (moved there in issue 23);
removed in the next release."""

from fgloc._deprecated import moved
from fgloc.registration import modes as _new

__getattr__ = moved(__name__, _new)
