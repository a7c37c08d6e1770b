"""The robot process: its options, its loop, the inbox that says when a step is ready, what it
publishes, the worker that validates brain swaps off the loop, its status figures and its log
lines.
"""
