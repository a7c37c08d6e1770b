"""The ``patternrl`` command line: one entry point, sub-commands loaded lazily."""
