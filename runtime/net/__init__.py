"""The network: opening Zenoh sessions with their options, and a swarm identity (mutual
TLS and Zenoh access control).
"""
