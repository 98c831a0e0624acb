"""Env kits: the offline data, train env, evaluator and action projection of each
``env.kind`` (generated PointMaze and Frozen-Lake data, and the Minari families).
"""
