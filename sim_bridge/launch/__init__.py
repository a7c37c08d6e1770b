"""Starting a swarm: ``patternrl launch`` (a world and one process per robot), the swarm's
Zenoh router, its keys and certificates (``patternrl keys``, a launch's own), and
``patternrl patterns``.
"""
