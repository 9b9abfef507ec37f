"""Moved to :mod:`onlinemap.studies.mapping` (every study lives in :mod:`onlinemap.studies`); importing this
module says so."""

raise ImportError("onlinemap.mapping_studies moved to onlinemap.studies.mapping (every study lives in onlinemap.studies)")
