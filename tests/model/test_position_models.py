"""The position models of the one engine (issue 22) keep one protocol (model.position_model.PositionModel): the
SCARA closed form, 001's free points and the volumetric machine each place their points, batched and not alike,
with the same row-compressed Jacobian convention, and the shared distance measurement reads any of them."""

import numpy as np
import pytest

from olti_drake.model.position_model import PositionModel


def _scara():
    from olti_drake.io.csvio import load_campaign
    from olti_drake.estimation.identification import IdentificationOptions, Identifier

    return Identifier(load_campaign("data/paper000/campaign.csv"), IdentificationOptions(model="errormap")).model


def _free_points():
    from olti_drake.model.free_points import FreePoints

    rng = np.random.default_rng(1)
    return FreePoints(rng.uniform(0, 300, (12, 3)), np.repeat([0, 1], 6), [[0, 0, 0], [50.0, 0, 20.0]])


def _volumetric():
    from olti_drake.model.volumetric3d import MachineConfig, VolumetricModel, VolumetricPositionModel

    cfg = MachineConfig(tool_offsets_mm=((0.0, 0.0, 100.0), (150.0, 0.0, 100.0)), knot_spacing_mm=100.0)
    rng = np.random.default_rng(2)
    cmd = rng.uniform([0, 0, 0], [400, 300, 250], (40, 3))
    return VolumetricPositionModel(VolumetricModel(cfg), cmd, np.repeat([0, 1], 20))


@pytest.mark.parametrize("make", (_scara, _free_points, _volumetric), ids=("scara", "free_points", "volumetric"))
def test_every_position_model_keeps_the_protocol(make):
    model = make()
    assert isinstance(model, PositionModel)
    assert model.n_params == len(model.names) and model.dim in (2, 3)
    rng = np.random.default_rng(3)
    x = model.start_vector() + 1e-3 * rng.standard_normal(model.n_params)
    p, J = model.jacobian(x)
    np.testing.assert_allclose(p, model.positions(x), rtol=0, atol=1e-12)
    assert p.shape == (model.n_points, model.dim)
    # Batched rows at every point equal the positions, and their compressed columns carry the dense Jacobian.
    points = np.arange(model.n_points)
    pb, cols, dp = model.rows(np.vstack([x, x]), points)
    np.testing.assert_allclose(pb[1], p, rtol=0, atol=1e-12)
    dense = J.tocsr().toarray().reshape(model.n_points, model.dim, model.n_params)
    for c in range(model.dim):
        rebuilt = np.zeros((model.n_points, model.n_params))
        np.add.at(rebuilt, (points[:, None], cols), np.broadcast_to(dp[c], pb.shape[:2] + cols.shape[1:])[1])
        np.testing.assert_allclose(rebuilt, dense[:, c], rtol=1e-12, atol=1e-12)
    assert model.implausible(model.start_vector()) == []
    assert isinstance(model.layout(np.zeros(model.n_params)), dict)
