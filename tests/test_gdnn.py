"""GDNN: shapes for every size and variable set, label encoding round trips, the Gaussian NLL, a tiny fit."""

import math

import numpy as np
import pytest
import torch

from simshear_gym.models.gdnn import (
    GDNN,
    UNIFORM_ANGLE_STD_DEG,
    VARIABLE_SETS,
    GDNNConfig,
    OutputSpec,
    beta_nll,
    decode,
    gaussian_nll,
    variable_set,
)

torch.set_num_threads(1)


def random_labels(variables, n, rng):
    return np.stack([rng.uniform(spec.low, spec.high, n) for spec in variables.variables], axis=1)


@pytest.mark.parametrize("size", [64, 128])
@pytest.mark.parametrize("name", sorted(VARIABLE_SETS))
def test_output_shapes_and_positive_std(size, name):
    torch.manual_seed(0)
    model = GDNN(GDNNConfig(image_size_px=size, variables=name)).eval()
    dim = VARIABLE_SETS[name].encoded_dim
    with torch.no_grad():
        mean, std = model(torch.rand(2, 1, size, size))
    assert mean.shape == std.shape == (2, dim)
    assert torch.all(std >= model.config.min_std) and torch.all(torch.isfinite(mean))
    units_mean, units_std = model.decode(mean, std)
    assert units_mean.shape == units_std.shape == (2, VARIABLE_SETS[name].dim)
    assert torch.all(units_std > 0)


def test_variable_sets():
    assert variable_set("surface").names == ("z_mm", "rx_deg", "ry_deg", "shear_x_mm", "shear_y_mm", "shear_rz_deg")
    edge = variable_set("edge")
    assert edge.names[:3] == ("y_mm", "z_mm", "edge_angle_deg") and edge.periodic[2]
    assert edge.encoded_dim == 7 and variable_set("mg400").encoded_dim == 4
    with pytest.raises(ValueError, match="expected one of"):
        variable_set("corner")
    with pytest.raises(ValueError, match="spans 360"):
        OutputSpec("angle_deg", "deg", -90, 90, periodic=True)


def test_config_validation():
    with pytest.raises(ValueError, match="multiple of 2\\*\\*4"):
        GDNNConfig(image_size_px=100)
    with pytest.raises(ValueError, match="same non-zero length"):
        GDNNConfig(conv_kernels=(5, 3))
    with pytest.raises(ValueError, match="unknown variable set"):
        GDNNConfig(variables="cylinder")
    with pytest.raises(ValueError, match=r"image must be \(B, 1, 64, 64\)"):
        GDNN(GDNNConfig(image_size_px=64))(torch.rand(2, 1, 32, 32))
    assert GDNNConfig(image_size_px=64, conv_channels=(16, 32, 64, 128)).flat_features == 128 * 4 * 4


@pytest.mark.parametrize("name", sorted(VARIABLE_SETS))
def test_encode_decode_round_trip(name):
    variables = variable_set(name)
    labels = random_labels(variables, 50, np.random.default_rng(1))
    encoded = variables.encode(labels)
    assert encoded.shape == (50, variables.encoded_dim)
    assert encoded.min() >= -1.0 - 1e-6 and encoded.max() <= 1.0 + 1e-6
    mean, std = variables.decode(encoded, torch.full_like(encoded, 0.1))
    np.testing.assert_allclose(mean.numpy(), labels, atol=1e-4)
    expected_std = [0.1 * spec.half_range for spec in variables.variables if not spec.periodic]
    linear = [not p for p in variables.periodic]
    np.testing.assert_allclose(std[:, linear].numpy(), np.broadcast_to(expected_std, (50, len(expected_std))),
                               rtol=1e-5)


def test_periodic_angle_across_180():
    edge = variable_set("edge")
    angles = np.array([179.5, -179.5, 180.0, -180.0, 0.0, 90.0, -90.0])
    labels = np.zeros((len(angles), edge.dim))
    labels[:, 1] = 4.0
    labels[:, 2] = angles
    encoded = edge.encode(labels)
    np.testing.assert_allclose(encoded[:, 2] ** 2 + encoded[:, 3] ** 2, 1.0, rtol=1e-6)
    np.testing.assert_allclose(encoded[0, 2:4], encoded[1, 2:4] * torch.tensor([-1.0, 1.0]), atol=1e-6)
    mean, _ = edge.decode(encoded, torch.full_like(encoded, 0.01))
    decoded = mean[:, 2].numpy()
    assert np.all((decoded >= -180.0) & (decoded < 180.0))
    circular_error = (decoded - angles + 180.0) % 360.0 - 180.0
    np.testing.assert_allclose(circular_error, 0.0, atol=1e-3)


def test_periodic_std_propagation():
    edge = variable_set("edge")
    mean = torch.zeros(2, edge.encoded_dim)
    std = torch.full_like(mean, 0.05)
    mean[0, 2:4] = torch.tensor([0.0, 1.0])  # angle 0: the sine's std sets the angle's std
    std[0, 2] = 0.1
    mean[1, 2:4] = torch.tensor([0.0, 1e-4])  # no direction: the std is capped at a uniform angle's
    _, units_std = decode(mean, std, "edge")
    assert units_std[0, 2].item() == pytest.approx(math.degrees(0.1), rel=1e-5)
    assert units_std[1, 2].item() == pytest.approx(UNIFORM_ANGLE_STD_DEG)


def test_gaussian_nll_closed_form():
    mean, std, target = torch.tensor([[0.0]]), torch.tensor([[2.0]]), torch.tensor([[1.0]])
    expected = 0.5 * math.log(2 * math.pi) + math.log(2.0) + 1.0 / 8.0
    assert gaussian_nll(mean, std, target).item() == pytest.approx(expected, rel=1e-6)
    # Sum over components, mean over samples; agrees with torch's loss plus the constant, times D.
    torch.manual_seed(0)
    mean, target = torch.randn(5, 3), torch.randn(5, 3)
    std = torch.rand(5, 3) + 0.1
    per_sample = gaussian_nll(mean, std, target, reduction="none")
    assert per_sample.shape == (5,)
    torch_loss = torch.nn.GaussianNLLLoss(full=True)(mean, target, std ** 2)
    assert gaussian_nll(mean, std, target).item() == pytest.approx(3 * torch_loss.item(), rel=1e-5)
    with pytest.raises(ValueError, match="reduction"):
        gaussian_nll(mean, std, target, reduction="sum")


def tiny_config(**overrides):
    settings = dict(image_size_px=32, conv_channels=(4, 8), conv_kernels=(5, 3), dense=(32,), dropout=0.0,
                    variables="edge")
    settings.update(overrides)
    return GDNNConfig(**settings)


def test_gradients_flow():
    torch.manual_seed(0)
    model = GDNN(tiny_config(dropout=0.1))
    variables = model.variables
    target = variables.encode(random_labels(variables, 4, np.random.default_rng(0)))
    loss = gaussian_nll(*model(torch.rand(4, 1, 32, 32)), target)
    loss.backward()
    for name, parameter in model.named_parameters():
        assert parameter.grad is not None and torch.isfinite(parameter.grad).all(), name
        assert parameter.grad.abs().sum() > 0, name


def test_tiny_fit_reduces_nll():
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    variables = variable_set("mg400")
    labels = random_labels(variables, 32, rng)
    target = variables.encode(labels)
    # A learnable toy: the brightness of four image quadrants encodes the four targets.
    images = torch.rand(32, 1, 32, 32) * 0.1
    for index in range(4):
        row, col = divmod(index, 2)
        images[:, 0, row * 16:(row + 1) * 16, col * 16:(col + 1) * 16] += 0.45 * (target[:, index, None, None] + 1)
    model = GDNN(tiny_config(variables="mg400"))
    optimiser = torch.optim.Adam(model.parameters(), lr=3e-3)

    def nll():
        with torch.no_grad():
            return gaussian_nll(*model(images), target).item()

    before = nll()
    for _ in range(8):
        optimiser.zero_grad()
        gaussian_nll(*model(images), target).backward()
        optimiser.step()
    after = nll()
    assert after < before - 1.0, (before, after)


def test_beta_nll_weights_and_limits():
    torch.manual_seed(1)
    mean, target = torch.randn(6, 3, requires_grad=True), torch.randn(6, 3)
    std = (torch.rand(6, 3) + 0.2).requires_grad_()
    # beta = 0 is the plain NLL.
    assert beta_nll(mean, std, target, 0.0).item() == pytest.approx(gaussian_nll(mean, std, target).item(), rel=1e-6)
    # beta = 1: the mean's gradient is the squared error's, whatever the std.
    beta_nll(mean, std, target, 1.0).backward()
    assert torch.allclose(mean.grad, (mean - target).detach() / 6, atol=1e-6)
    # The std's optimum is unchanged: at std = |error| the gradient of each component vanishes for any beta.
    std_at_error = (mean - target).abs().detach().clamp_min(1e-3).requires_grad_()
    beta_nll(mean.detach(), std_at_error, target, 0.5).backward()
    assert std_at_error.grad.abs().max().item() < 1e-5
    with pytest.raises(ValueError, match="beta"):
        beta_nll(mean, std, target, 1.5)


def test_untrained_network_predicts_centre_and_initial_std():
    torch.manual_seed(0)
    model = GDNN(tiny_config(initial_std=0.5, dropout=0.0)).eval()
    mean, std = model(torch.rand(8, 1, 32, 32))
    assert mean.abs().max().item() < 0.5
    assert std.mean().item() == pytest.approx(0.5, abs=0.1)
    with pytest.raises(ValueError, match="initial_std"):
        tiny_config(initial_std=0.005)


def test_pooling_before_the_elu_is_the_map_of_the_elu_before_pooling():
    """Each conv level pools, then applies the ELU (on a quarter of the pixels): ELU being increasing, the same
    outputs and gradients as the ELU first, with the same state dict."""
    torch.manual_seed(0)
    model = GDNN(tiny_config())
    layers, elu_first, index = list(model.features), [], 0
    while index < len(layers):
        if isinstance(layers[index], torch.nn.MaxPool2d):
            assert isinstance(layers[index + 1], torch.nn.ELU)
            elu_first += [layers[index + 1], layers[index]]
            index += 2
        else:
            elu_first.append(layers[index])
            index += 1
    reference = torch.nn.Sequential(*elu_first)
    assert reference.state_dict().keys() == model.features.state_dict().keys()
    images = torch.rand(4, 1, 32, 32)
    got, expected = model.features(images), reference(images)
    assert torch.equal(got, expected)
    weights = torch.randn_like(got)
    grad_got = torch.autograd.grad((got * weights).sum(), model.features[0].weight)[0]
    grad_expected = torch.autograd.grad((reference(images) * weights).sum(), model.features[0].weight)[0]
    torch.testing.assert_close(grad_got, grad_expected)


def test_frozen_copy_gives_the_same_outputs():
    torch.manual_seed(0)
    model = GDNN(tiny_config(dropout=0.1))
    model.train()
    model(torch.rand(4, 1, 32, 32))  # move the batch-norm statistics away from their initial values
    model.eval()
    images = torch.rand(3, 1, 32, 32)
    with torch.no_grad():
        expected = model(images)
        frozen = model.frozen()(images)
    for a, b in zip(expected, frozen):
        assert torch.allclose(a, b, atol=1e-5)
    assert model.training is False
