"""The algorithm-independent offline-to-online run and the :class:`Learner` protocol.

Data, replay, collectors, the run on TorchRL's ``Trainer``, evaluation, logging, checkpoint and resume, and
the :class:`Learner` protocol each algorithm implements.
"""
