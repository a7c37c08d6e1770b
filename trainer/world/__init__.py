"""The training world: batch numpy over E envs x N robots, its contact model (compiled),
its reward, and the PettingZoo environment around it.
"""
