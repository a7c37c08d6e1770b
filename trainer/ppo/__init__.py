"""Pattern-RL PPO, Algorithm 1's parts: the networks, the paper brain's fixed front end and
its ranks, rollout memory with returns and advantages, one update, and the export to ONNX
with its manifest.
"""
