"""What estimators share.

The :class:`~idbench.estimate.filter.Filter` base, parameter transforms, the
low-rank covariance and the reference posterior.
"""
