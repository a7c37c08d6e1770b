"""Offline training: the batch world, Pattern-RL PPO, ONNX export and evaluation."""
