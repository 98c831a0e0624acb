"""Parts shared by several algorithms, one home each.

The critics, the actor networks, the Laplace refit schedule, the planner's offline stage and
augmentation, and Cal-QL's Monte-Carlo labels.
"""
