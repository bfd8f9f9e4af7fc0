"""The filter evaluation on simulated sequences: sequence labels, the filter on synthetic readings, end to end."""

import numpy as np
import pytest
import torch

from simshear_gym.evaluate.metrics import pose_shear_labels
from simshear_gym.evaluate.posenet_filter import (
    FilterSettings,
    SequenceConfig,
    contact_sequence,
    evaluate_sequence,
    lag_steps,
    run_filter,
)
from simshear_gym.models.gdnn import GDNN, GDNNConfig, variable_set
from simshear_gym.models.posenet_io import save_posenet

torch.set_num_threads(1)


@pytest.mark.parametrize("contact", ["surface", "edge"])
def test_sequence_starts_at_touch_and_stays_in_the_training_ranges(contact):
    poses, moves = contact_sequence(SequenceConfig(contact=contact, steps=100))
    assert poses.shape == moves.shape == (100, 6)
    assert np.allclose(moves[0], 0.0)
    labels = pose_shear_labels(poses, moves, variable_set(contact))  # the move stands in for the shear here
    for index, spec in enumerate(variable_set(contact).variables):
        assert labels[:, index].min() >= spec.low and labels[:, index].max() <= spec.high, spec.name
    if contact == "edge":  # the edge angle crosses +-180
        assert np.abs(np.diff(poses[:, 5])).max() > 300


def test_filter_reduces_noise_without_lag_on_synthetic_readings():
    variables = variable_set("edge")
    poses, moves = contact_sequence(SequenceConfig(contact="edge", steps=200))
    truth = pose_shear_labels(poses, moves, variables)
    rng = np.random.default_rng(0)
    std = np.tile([0.5, 0.2, 8.0, 1.0, 1.0, 1.5], (len(truth), 1))
    readings = truth + rng.normal(size=truth.shape) * std
    readings[:, 2] = np.remainder(readings[:, 2] + 180.0, 360.0) - 180.0
    filtered, filtered_std = run_filter(readings, std, truth, variables, FilterSettings())
    raw_error = np.abs(readings - truth)
    filtered_error = np.abs(filtered - truth)
    raw_error[:, 2] = np.abs(np.remainder(readings[:, 2] - truth[:, 2] + 180.0, 360.0) - 180.0)
    filtered_error[:, 2] = np.abs(np.remainder(filtered[:, 2] - truth[:, 2] + 180.0, 360.0) - 180.0)
    assert np.all(filtered_error.mean(axis=0) < 0.5 * raw_error.mean(axis=0))
    assert np.all(filtered_std[-1] < std[-1])
    # The filter's own dynamics add no lag: fed exact readings, it follows the moving contact step for step.
    exact, _ = run_filter(truth.astype(np.float64), std, truth, variables, FilterSettings())
    for index, spec in enumerate(variables.variables):
        assert lag_steps(exact[:, index], truth[:, index], spec.periodic, 3) == 0, spec.name


def test_lag_of_a_delayed_signal():
    signal = np.sin(np.linspace(0, 6, 100))
    delayed = np.concatenate([[0, 0], signal[:-2]])
    assert lag_steps(delayed, signal, False, 4) == 2


def test_evaluate_sequence_end_to_end(tmp_path):
    torch.manual_seed(0)
    path = save_posenet(tmp_path / "gdnn.pt", GDNN(GDNNConfig(variables="surface")).eval())
    result = evaluate_sequence(path, SequenceConfig(contact="surface", steps=8), FilterSettings(), max_lag=2)
    variables, truth, raw, filtered = result.pop("_series")
    assert truth.shape == raw.shape == filtered.shape == (8, 6)
    assert set(result["variables"]) == set(variables.names)
    for figures in result["variables"].values():
        assert figures["filter_lag_steps"] == 0
        assert figures["raw_mae"] > 0 and np.isfinite(figures["filtered_mae"])
    with pytest.raises(ValueError, match="'surface' variables, not 'edge'"):
        evaluate_sequence(path, SequenceConfig(contact="edge", steps=8), FilterSettings())
