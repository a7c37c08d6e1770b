"""The MCAP log: its layout and protobuf schemas, writing it, reading it back (recovery,
columns, phases), and everything done with a log afterwards: the report, plots,
counterfactual brains, playback onto Zenoh, ``patternrl replay`` and ``patternrl record``.
"""
