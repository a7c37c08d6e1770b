"""The pymunk world over Zenoh, MCAP recording, the launcher, replay and analysis."""
