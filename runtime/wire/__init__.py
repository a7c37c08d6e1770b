"""The wire: every message with its encoding (field tables, codec, the batched poses of a
step) and the Zenoh key expressions they travel on. Both sides of the link, robots and
world, speak through this package only.
"""
