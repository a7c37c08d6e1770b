"""The per-robot runtime and everything both sides share.

Light on purpose: numpy, scipy, onnxruntime and zenoh only. Holds the world
constants, the patterns, the formation geometry, the observation builders, the
safety filter, the wire messages and the Zenoh key expressions.
"""
