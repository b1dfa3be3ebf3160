"""Errors and warnings of the chunk store.

The store never imports the application; a CLI layer turns a :class:`StoreError`
into its own user-error type. Every message names the folder or file and what is
wrong with it.
"""

from __future__ import annotations


class StoreError(ValueError):
    """The folder, a chunk or an argument is unusable; the message is meant for the end user."""


class LockedError(StoreError):
    """Another run holds the folder's lock."""


class StoreWarning(UserWarning):
    """Something was repaired on the way (a damaged chunk is computed again)."""
