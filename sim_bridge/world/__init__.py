"""The simulated world over Zenoh: the pymunk physics, the world process and its phase loop,
robots joining and leaving, the formation measured per phase, brains chosen and swapped
between phases, and ``patternrl sim``.
"""
