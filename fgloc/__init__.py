"""fgloc: self-localization of roadside 4D radar sensors from the traffic they track."""

__version__ = "0.1.0"
