"""What the learned methods (BTEL, btel-codes, RYTH) train with: linear classifiers, their
solvers and stored hyperplanes, supervised feature selection, and distributed fitting."""
