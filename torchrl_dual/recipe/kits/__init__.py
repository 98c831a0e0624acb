"""Env kits: the offline data, train env, evaluator and action projection of each ``env.kind``.

Generated PointMaze and Frozen-Lake data, and the Minari families.
"""
