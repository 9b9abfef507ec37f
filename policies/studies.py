"""Moved to :mod:`onlinemap.studies.exploration` (every study lives in :mod:`onlinemap.studies`); importing this
module says so."""

raise ImportError("policies.studies moved to onlinemap.studies.exploration (every study lives in onlinemap.studies)")
