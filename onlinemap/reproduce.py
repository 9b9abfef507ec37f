"""Moved to :mod:`onlinemap.studies.corridor` (every study lives in :mod:`onlinemap.studies`); importing this
module says so."""

raise ImportError("onlinemap.reproduce moved to onlinemap.studies.corridor (every study lives in onlinemap.studies)")
