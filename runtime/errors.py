"""The one error type for bad user input.

Everything a user can get wrong (a command-line option, a pattern file, a brain
file, a log file, a Zenoh endpoint) raises :class:`InputError` or one of its
subclasses with a one-line reason. Every command catches ``InputError`` at its
edge, prints ``error: <reason>`` and exits non-zero: an expected mistake never
shows a traceback.
"""

from __future__ import annotations


class InputError(ValueError):
    """Bad user input, with a one-line reason fit to print as it is."""
