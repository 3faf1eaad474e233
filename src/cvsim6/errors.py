"""Errors a user fixes by changing a setting or an input, not the code.

The workflow's rule adapter (``workflow/scripts/call.py``) reports these as one line naming
what failed and what to change, without a traceback; every other exception is a bug and is
logged with its traceback.
"""


class UserFacingError(Exception):
    """An error whose message alone tells the user what failed and which setting avoids it."""


class DownloadError(UserFacingError, OSError):
    """A public file could not be fetched; the message names the URL and the config key of a
    local copy."""
