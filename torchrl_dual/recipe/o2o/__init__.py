"""The algorithm-independent offline-to-online run: data, replay, collectors, the
online loop, evaluation, logging, checkpoint and resume, and the :class:`Learner`
protocol each algorithm implements.
"""
