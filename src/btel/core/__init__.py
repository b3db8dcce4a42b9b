"""The building blocks every estimator is made of: input checks, the storage rule and budgets, model files,
the front end (normalisation, delta descriptors, whitening) and its row operations, top-k, threads, limits.

Nothing here knows a method: :mod:`btel.methods` builds on these.
"""
