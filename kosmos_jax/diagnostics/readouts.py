"""Linear readouts of a model's features, fit in closed form (the probes' shared arithmetic)."""

from __future__ import annotations

import numpy as np


def ridge_fit(train_x: np.ndarray, targets: np.ndarray, ridge: float):
    """A linear map from standardised features [N, D] (plus a bias) to `targets` [N, K], ridge penalty
    `ridge` per example; returns the map as a function of features [M, D] -> [M, K]."""
    mean, scale = train_x.mean(0), train_x.std(0) + 1e-6
    design = lambda x: np.c_[(x - mean) / scale, np.ones(len(x))]
    a = design(train_x)
    weights = np.linalg.solve(a.T @ a + ridge * len(a) * np.eye(a.shape[1]), a.T @ targets)
    return lambda x: design(x) @ weights


def class_readout(train_x: np.ndarray, train_labels: np.ndarray, classes: int, ridge: float):
    """A ridge fit to one-hot labels read by its largest output: features [M, D] -> labels [M]."""
    fit = ridge_fit(train_x, np.eye(classes)[train_labels], ridge)
    return lambda x: fit(x).argmax(axis=1)


def accuracy(predicted: np.ndarray, labels: np.ndarray) -> float:
    """Share (percent) of `predicted` equal to `labels`, two decimals."""
    return round(float((np.asarray(predicted) == np.asarray(labels)).mean() * 100), 2)


def majority_share(train_labels: np.ndarray, labels: np.ndarray) -> float:
    """What always answering the training labels' most common class scores on `labels` (percent)."""
    common = np.bincount(train_labels).argmax()
    return accuracy(np.full(len(labels), common), labels)
