"""Moved to :mod:`onlinemap.studies.accuracy` (every study lives in :mod:`onlinemap.studies`); importing this
module says so."""

raise ImportError("onlinemap.compare moved to onlinemap.studies.accuracy (every study lives in onlinemap.studies)")
