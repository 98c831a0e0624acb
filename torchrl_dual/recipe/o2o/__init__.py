"""The algorithm-independent offline-to-online run and the :class:`Learner` protocol.

Data, replay, collectors, the online loop, evaluation, logging, checkpoint and resume, and
the :class:`Learner` protocol each algorithm implements.
"""
