"""The live view: the Foxglove scene of a step, the world's Foxglove server, and a minimal
Foxglove client.
"""
