"""The per-robot runtime and everything both sides share.

Light on purpose: numpy, scipy, onnxruntime and zenoh only. At the top, the shared
base (the world constants, array types, the input error, log lines); below it the
decision's compiled math (``core``), the decision itself (``decision``), the wire
messages and keys (``wire``), brains (``brain``), the robot process (``robot``) and
Zenoh sessions and identities (``net``).
"""
