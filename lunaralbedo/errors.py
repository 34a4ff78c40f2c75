"""Typed exceptions of lunaralbedo.

Every error raised on bad input derives from :class:`LunarAlbedoError`, names the
offending file (or settings key) and says what is wrong.  The CLI turns them into
a one-line message and a non-zero exit status.
"""
from __future__ import annotations


class LunarAlbedoError(Exception):
    """Base class of every error the package raises on purpose."""

    exit_code = 2


class SettingsError(LunarAlbedoError):
    """A settings file is unreadable, has an unknown key or an invalid value."""


class InputError(LunarAlbedoError):
    """An input file (raster, position list, cube, kernel) is missing or malformed."""


class DuplicateKeyError(InputError):
    """Two DRG files share the same 11-character lookup key."""


class MissingPositionError(InputError):
    """A DRG has no line in the Sun or spacecraft position file."""


class IsisError(InputError):
    """An ISIS3 cube or label cannot be read or lacks a required group/table."""


class SpiceError(InputError):
    """A kernel is missing, a time is not covered or a frame is unknown."""


class SolverError(LunarAlbedoError):
    """The solve cannot proceed (e.g. no image overlaps the simulation box)."""


class ResumeError(LunarAlbedoError):
    """A run cannot be resumed (the checkpoint belongs to other settings)."""
