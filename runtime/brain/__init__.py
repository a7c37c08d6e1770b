"""Brains: reading, validating and running a brain file (ONNX or a rule), its manifest,
its ed25519 signature, ``patternrl brain`` (keys, sign, verify) and ``patternrl swap``
(the operator's side of a hot swap).
"""
