"""The reproduced BayesRace data sets (SPEC §3) and their windows, split and scaling."""

from __future__ import annotations

import numpy as np
import pytest

from cape.data.windows import FEATURES, StandardScaler, make_windows, split_indices

# Published fingerprints of DYN-PP-ETHZ and DYN-PP-ETHZMobil (the acceptance list).
ETHZ_DSTATES_3_8_500 = [2.1328846289, -0.0303090537, 0.5838382657, 0.4452513182, 0.0160577259]
ETHZ_INPUTS_999 = [-0.0054280906, -0.1095121]
ETHZMOBIL_DSTATES_3_1000 = 2.7995394698


def test_published_fingerprints(datasets) -> None:
    ethz, mobil = datasets["ETHZ"], datasets["ETHZMobil"]
    np.testing.assert_allclose(ethz["dstates"][3:8, 500], ETHZ_DSTATES_3_8_500, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ethz["inputs"][:, 999], ETHZ_INPUTS_999, rtol=0, atol=1e-9)
    assert abs(mobil["dstates"][3, 1000] - ETHZMOBIL_DSTATES_3_1000) <= 1e-9


@pytest.mark.parametrize("track", ["ETHZ", "ETHZMobil"])
def test_published_shapes_and_structure(datasets, track: str) -> None:
    d = datasets[track]
    assert d["time"].shape == (1001,) and d["states"].shape == (6, 1001)
    assert (
        d["dstates"].shape == (8, 1001)
        and d["inputs"].shape == (2, 1000)
        and d["vrefs"].shape == (1001,)
    )
    np.testing.assert_allclose(d["time"][[0, 1, 1000]], [0.0, 0.02, 20.0])
    # column 0 of dstates is zero except vx = 0.1
    np.testing.assert_array_equal(d["dstates"][:, 0], [0, 0, 0, 0.1, 0, 0, 0, 0])
    # dstates[6:8, k+1] hold the inputs applied at step k
    np.testing.assert_allclose(d["dstates"][6:8, 1:], d["inputs"], atol=1e-15)
    # vrefs[k+1] = T_k/KP + vx_k, vrefs[0] = 0.1
    assert d["vrefs"][0] == 0.1
    np.testing.assert_allclose(
        d["vrefs"][1:], d["inputs"][0] / 0.6 + d["states"][3, :-1], atol=1e-12
    )
    # unclipped: the published data exceed the actuator limits somewhere
    assert np.abs(d["inputs"][1]).max() > 0.35 or d["inputs"][0].min() < -0.1


def test_dstates_is_the_euler_side_trajectory(datasets) -> None:
    """Both trajectories start at the raceline's first point; dstates takes Euler steps and
    drifts from the RKF states."""
    d = datasets["ETHZ"]
    x0, y0, psi0 = d["states"][:3, 0]
    assert psi0 == pytest.approx(-np.pi / 4, abs=0)
    # first Euler step from [X0, Y0, ψ0, 0.1, 0, 0]: position moves by Ts·0.1·(cos ψ0, sin ψ0)
    np.testing.assert_allclose(
        d["dstates"][:3, 1],
        [x0 + 0.002 * np.cos(psi0), y0 + 0.002 * np.sin(psi0), psi0],
        atol=1e-15,
    )
    assert np.abs(d["states"][3, 200] - d["dstates"][3, 200]) > 1e-4


def test_generation_is_deterministic(datasets, track_dir, config) -> None:
    from cape.data.bayesrace import ProtocolSettings, generate_dataset
    from cape.specs.tracks import DataSettings
    from cape.tracks.track import load_raceline
    from cape.vehicle.params import GROUND_TRUTH

    again = generate_dataset(
        load_raceline(track_dir, "ethzMobil_raceline.npz"),
        GROUND_TRUTH,
        ProtocolSettings.of(DataSettings.from_config(config), "ETHZMobil"),
    )
    for key, value in datasets["ETHZMobil"].items():
        np.testing.assert_array_equal(again[key], value)


def test_windows_h5_give_995_windows(datasets) -> None:
    w = make_windows(datasets["ETHZ"], history=5)
    assert len(w) == 995 and w.features.shape == (995, 5, 7) and w.labels.shape == (995, 3)
    assert w.history == 5 and len(FEATURES) == 7


@pytest.mark.parametrize("history", [1, 5, 7, 10])
def test_window_contents(datasets, history: int) -> None:
    d = datasets["ETHZ"]
    w = make_windows(d, history)
    assert len(w) == 1000 - history
    i = 123
    rows = w.features[i]
    ks = np.arange(i, i + history)
    np.testing.assert_array_equal(rows[:, :5], d["dstates"][3:8, ks].T)
    u_prev = np.where(ks[:, None] > 0, d["inputs"][:, np.maximum(ks - 1, 0)].T, 0.0)
    np.testing.assert_array_equal(rows[:, 5:], d["inputs"][:, ks].T - u_prev)
    np.testing.assert_array_equal(w.labels[i], d["dstates"][3:6, i + history])
    # the physics step applies fb + Δ of the last row: the input of step i+H−1
    np.testing.assert_allclose(
        rows[-1, 3:5] + rows[-1, 5:], d["inputs"][:, i + history - 1], atol=1e-15
    )
    # first window: Δu_0 = u_0 − 0
    np.testing.assert_array_equal(w.features[0, 0, 5:], d["inputs"][:, 0])


def test_window_length_must_fit(datasets) -> None:
    with pytest.raises(ValueError, match="history length"):
        make_windows(datasets["ETHZ"], 0)
    with pytest.raises(ValueError, match="history length"):
        make_windows(datasets["ETHZ"], 1000)


def test_seeded_split() -> None:
    train, val = split_indices(995, 0.9, seed=0)
    assert len(train) == 895 and len(val) == 100
    assert np.intersect1d(train, val).size == 0
    np.testing.assert_array_equal(np.sort(np.concatenate([train, val])), np.arange(995))
    again_train, _ = split_indices(995, 0.9, seed=0)
    np.testing.assert_array_equal(train, again_train)
    other_train, _ = split_indices(995, 0.9, seed=1)
    assert not np.array_equal(train, other_train)
    with pytest.raises(ValueError, match="train_fraction"):
        split_indices(10, 1.0, seed=0)


def test_scaler_is_fitted_on_the_training_split_only(datasets) -> None:
    w = make_windows(datasets["ETHZ"], 5)
    train, val = split_indices(len(w), 0.9, seed=0)
    scaler = StandardScaler.fit(w.features[train])
    flat = w.features[train].reshape(-1, 7)
    np.testing.assert_allclose(scaler.mean, flat.mean(axis=0))
    np.testing.assert_allclose(scaler.scale, flat.std(axis=0))
    scaled = scaler.transform(w.features[train]).reshape(-1, 7)
    np.testing.assert_allclose(scaled.mean(axis=0), 0.0, atol=1e-12)
    np.testing.assert_allclose(scaled.std(axis=0), 1.0, atol=1e-12)
    assert not np.allclose(StandardScaler.fit(w.features[val]).mean, scaler.mean)
    restored = StandardScaler.from_dict(scaler.to_dict())
    np.testing.assert_array_equal(
        restored.inverse_transform(restored.transform(w.features[val])),
        scaler.inverse_transform(scaler.transform(w.features[val])),
    )
    const = StandardScaler.fit(np.ones((4, 2, 3)))
    np.testing.assert_array_equal(const.scale, 1.0)
