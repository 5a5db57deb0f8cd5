"""The learned models (SPEC §4): registry, architecture, physics layer, guard, fast path."""

from __future__ import annotations

import copy
import json
import subprocess
import sys

import casadi as ca
import numpy as np
import pytest
import torch

from cape.data.windows import make_windows
from cape.errors import CapeError
from cape.models import model_class
from cape.models.base import LearnedModel
from cape.models.network import NumpyNetwork, load_network, save_network
from cape.models.physics import ModelPhysics
from cape.models.trained import TrainedModel
from cape.paper import PARAMETER_COUNT_CHECK
from cape.training.loop import build_model
from cape.vehicle import GROUND_TRUTH, velocity_derivatives

TS = 0.02
GT = GROUND_TRUTH.as_dict()


def _phi_truth(model: LearnedModel, n: int, **extra: float) -> np.ndarray:
    values = {**GT, "h": 0.0, "tau_delta": TS, "tau_T": TS, **extra}
    return np.tile([values[name] for name in model.param_names], (n, 1))


def _step(model: LearnedModel, features: np.ndarray, phi: np.ndarray) -> np.ndarray:
    last = torch.as_tensor(features[:, -1, :])
    out = model.step_velocities(
        last[:, 0], last[:, 1], last[:, 2], (last[:, 3], last[:, 4]),
        (last[:, 3] + last[:, 5], last[:, 4] + last[:, 6]), torch.as_tensor(phi),
    )  # fmt: skip
    return torch.stack(out, dim=-1).numpy()


@pytest.fixture(scope="module")
def models(config) -> dict[str, LearnedModel]:
    return {
        name: build_model(name, config["models"][name], TS, seed=0)
        for name in ("dpm", "ddm", "epm")
    }


def test_registry_maps_names_to_classes(config) -> None:
    for name in ("dpm", "ddm", "epm"):
        cls = model_class(name, config["models"][name])
        assert issubclass(cls, ModelPhysics) and cls.name == name
    with pytest.raises(CapeError, match=r"unknown model 'gpt'.*models.gpt.module"):
        model_class("gpt")
    with pytest.raises(CapeError, match=r"models\.gpt\.module`: cannot import 'mine/gpt\.py' \("):
        model_class("gpt", {"module": "mine/gpt.py"})
    with pytest.raises(CapeError, match=r"`models\.mine\.module`: cannot import 'no_such_module'"):
        model_class("mine", {"module": "no_such_module"})
    with pytest.raises(CapeError, match="does not register it"):
        model_class("mine", {"module": "cape.models.ddm"})


@pytest.mark.parametrize(("name", "gru", "fc"), [("dpm", 8, 3), ("ddm", 7, 17), ("epm", 7, 8)])
def test_architecture_matches_the_paper(models, name: str, gru: int, fc: int) -> None:
    model = models[name]
    assert model.n_parameters() == pytest.approx(PARAMETER_COUNT_CHECK[name], rel=0.02)
    assert model.gru_layers() == gru and model.fc_layers() == fc
    assert isinstance(model.gru, torch.nn.GRU) and model.gru.num_layers == gru


def test_ddm_physics_with_true_parameters_reproduces_the_labels(models, datasets) -> None:
    """The DDM's structure contains the data-generating model: with Φ = the truth, its physics
    step gives the labels (the Euler side trajectory) to rounding."""
    w = make_windows(datasets["ETHZ"], 5)
    pred = _step(models["ddm"], w.features, _phi_truth(models["ddm"], len(w)))
    np.testing.assert_allclose(pred, w.labels, rtol=0, atol=1e-12)


def test_epm_with_no_load_transfer_and_no_lag_equals_ddm(models, datasets) -> None:
    w = make_windows(datasets["ETHZMobil"], 7)
    ddm = _step(models["ddm"], w.features, _phi_truth(models["ddm"], len(w)))
    epm = _step(
        models["epm"],
        w.features,
        _phi_truth(models["epm"], len(w), h=0.0, tau_delta=0.01, tau_T=0.005),
    )
    np.testing.assert_array_equal(epm, ddm)


def test_epm_terms_against_the_shared_equations(models, datasets) -> None:
    """Load transfer and actuator lag, checked term by term with the vehicle equations."""
    w = make_windows(datasets["ETHZMobil"], 7)
    f = w.features[::50]
    phi = _phi_truth(models["epm"], len(f), h=0.03, tau_delta=0.08, tau_T=0.04)
    got = _step(models["epm"], f, phi)
    last = f[:, -1, :]
    # lag: applied = fb + min(1, Ts/τ)·(cmd − fb) = fb + Δ·Ts/τ
    throttle = last[:, 3] + last[:, 5] * (TS / 0.04)
    delta = last[:, 4] + last[:, 6] * (TS / 0.08)
    # load transfer, written out: Fz_f = m(g·lr − h·ax)/L over its static value, likewise rear
    frx = (GT["Cm1"] - GT["Cm2"] * last[:, 0]) * throttle - GT["Cr0"] - GT["Cr2"] * last[:, 0] ** 2
    m, lf, lr, g = GT["m"], GT["lf"], GT["lr"], 9.81
    kf = (m * (g * lr - 0.03 * frx / m) / (lf + lr)) / (m * g * lr / (lf + lr))
    kr = (m * (g * lf + 0.03 * frx / m) / (lf + lr)) / (m * g * lf / (lf + lr))
    from cape.vehicle.dynamics import tire_forces

    ffy, fry = tire_forces(last[:, 0], last[:, 1], last[:, 2], delta, GT)
    ffy, fry = ffy * kf, fry * kr
    dvx = (frx - ffy * np.sin(delta)) / m + last[:, 1] * last[:, 2]
    dvy = (fry + ffy * np.cos(delta)) / m - last[:, 0] * last[:, 2]
    dw = (ffy * lf * np.cos(delta) - fry * lr) / GT["Iz"]
    expected = last[:, :3] + TS * np.stack([dvx, dvy, dw], axis=1)
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-13)
    assert np.abs(got - _step(models["epm"], f, _phi_truth(models["epm"], len(f)))).max() > 1e-6


def test_dpm_uses_its_predicted_longitudinal_force(models, datasets) -> None:
    w = make_windows(datasets["ETHZ"], 10)
    f = w.features[::40]
    frx = np.linspace(-0.1, 0.2, len(f))
    phi = np.column_stack(
        [np.tile([GT[n] for n in models["dpm"].param_names[:-1]], (len(f), 1)), frx]
    )
    got = _step(models["dpm"], f, phi)
    last = f[:, -1, :]
    p = {**GT, "Shf": 0.0, "Svf": 0.0, "Shr": 0.0, "Svr": 0.0}
    dv = velocity_derivatives(
        last[:, 0], last[:, 1], last[:, 2], np.nan, last[:, 4] + last[:, 6], p, frx=frx
    )
    np.testing.assert_allclose(got, last[:, :3] + TS * np.stack(dv, axis=1), rtol=1e-12, atol=1e-13)
    assert not models["dpm"].throttle_path


@pytest.mark.parametrize("name", ["dpm", "ddm", "epm"])
def test_physics_step_is_backend_neutral(models, name: str) -> None:
    """The same step on NumPy floats and CasADi symbols (the NMPC's internal model)."""
    model = models[name]
    phi = (
        _phi_truth(model, 1, h=0.02, tau_delta=0.05, tau_T=0.03)[0]
        if name != "dpm"
        else np.r_[[GT[n] for n in model.param_names[:-1]], 0.05]
    )
    args = (1.7, 0.05, 0.8, (0.3, 0.1), (0.35, 0.12))
    num = np.array(model.step_velocities(*args, phi))
    sym = ca.SX.sym("phi", len(phi))
    f = ca.Function("f", [sym], [ca.vertcat(*model.step_velocities(*args, sym))])
    np.testing.assert_allclose(np.array(f(phi)).ravel(), num, rtol=1e-13)
    t = lambda v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
    torch_out = model.step_velocities(
        *(t(a) for a in args[:3]), tuple(map(t, args[3])), tuple(map(t, args[4])), t(phi)
    )
    np.testing.assert_allclose([t.item() for t in torch_out], num, rtol=1e-13)


@pytest.mark.parametrize("name", ["ddm", "epm"])
def test_guard_keeps_every_output_inside_its_bounds(models, config, name: str) -> None:
    model = copy.deepcopy(models[name])
    with torch.no_grad():
        for p in model.parameters():
            p.mul_(50.0)  # saturate every unit
    rng = np.random.default_rng(3)
    extreme = rng.choice([-1e6, -1e3, 0.0, 1e3, 1e6], size=(64, model.history, 7))
    phi = model.phi(torch.as_tensor(extreme)).detach().numpy()
    bounds = config["models"][name]["bounds"]
    lower = np.array([bounds[n][0] for n in model.param_names])
    upper = np.array([bounds[n][1] for n in model.param_names])
    assert np.isfinite(phi).all()
    assert (phi >= lower).all() and (phi <= upper).all()
    assert (phi == upper).any() or (phi == lower).any()  # really saturated


def _held_to_the_training_graph(
    model: LearnedModel, datasets, tmp_path, compile_settings: dict | None
) -> NumpyNetwork:
    """The closed loop's path (weights exported to network.npz, read back without PyTorch,
    compiled with ``compile_settings``) against the training graph on ETHZMobil windows, at
    the tolerances the closed loop relies on."""
    model = copy.deepcopy(model)
    w = make_windows(datasets["ETHZMobil"], model.history)
    flat = w.features.reshape(-1, 7)
    model.set_scaler(flat.mean(axis=0), flat.std(axis=0))
    features = w.features[::7]
    with torch.no_grad():
        ref = model(torch.as_tensor(features)).numpy()
        ref_phi = model.phi(torch.as_tensor(features)).numpy()
    save_network(tmp_path / "network.npz", model.network_arrays())
    network = load_network(tmp_path / "network.npz", compile_settings)
    fast = TrainedModel(model.physics, network)
    pred = np.array([fast.predict(x) for x in features])
    phi = np.array([fast.phi(x) for x in features])
    # the next state, what the closed loop consumes: ≤ 1e-6 relative
    assert np.max(np.abs(pred - ref) / np.abs(ref).max(axis=0)) <= 1e-6
    # Φ: within the float32 rounding of the training graph itself (relative to each range)
    assert np.max(np.abs(phi - ref_phi) / np.maximum(np.abs(ref_phi).max(axis=0), 1e-12)) <= 1e-4
    return network


def _compile_settings(tmp_path) -> dict:
    return {"enabled": True, "cache": str(tmp_path / "cache"), "compiler": "gcc", "flags": ["-O1"]}


@pytest.mark.parametrize("name", ["dpm", "ddm", "epm"])
def test_exported_numpy_network_matches_the_training_graph(
    models, datasets, name: str, tmp_path
) -> None:
    """Uncompiled (CasADi's virtual machine and the NumPy trunk), the real architectures."""
    network = _held_to_the_training_graph(models[name], datasets, tmp_path, None)
    assert network.library is None


@pytest.mark.slow
@pytest.mark.parametrize("name", ["dpm", "ddm", "epm"])
def test_compiled_phi_of_the_real_architectures_matches_the_training_graph(
    models, datasets, name: str, tmp_path
) -> None:
    """The default path of the study's models: Φ as one compiled C function (DPM's GRU takes
    most of a minute to compile)."""
    settings = _compile_settings(tmp_path)
    network = _held_to_the_training_graph(models[name], datasets, tmp_path, settings)
    assert network.library is not None


# small networks with every layer kind, a guard and a plain output, a GRU and none, and widths
# that are no multiple of the compiled product's 8 lanes: quick to compile
SMALL = {
    "ddm-mish": ("ddm", {"gru": {"hidden": 3, "layers": 2}, "head": {"width": 13, "layers": 2,
                 "activation": "mish"}}),
    "epm-gelu-layer-norm": ("epm", {"gru": {"hidden": 4, "layers": 2}, "head": {"width": 21,
                            "layers": 3, "activation": "gelu", "layer_norm_after": [1, 3]}}),
    "dpm-relu-no-gru": ("dpm", {"gru": {"hidden": 1, "layers": 0}, "head": {"width": 11,
                        "layers": 2, "activation": "relu"}}),
    "dpm-tanh": ("dpm", {"gru": {"hidden": 2, "layers": 1}, "head": {"width": 9, "layers": 1,
                 "activation": "tanh"}}),
}  # fmt: skip


@pytest.mark.parametrize("variant", sorted(SMALL))
@pytest.mark.parametrize("compiled", [True, False], ids=["compiled", "uncompiled"])
def test_both_paths_of_every_layer_kind_match_the_training_graph(
    config, datasets, variant: str, compiled: bool, tmp_path
) -> None:
    name, changes = SMALL[variant]
    spec = {**copy.deepcopy(config["models"][name]), **changes}
    model = build_model(name, spec, TS, seed=1)
    settings = _compile_settings(tmp_path) if compiled else None
    network = _held_to_the_training_graph(model, datasets, tmp_path, settings)
    assert (network.library is not None) == compiled
    window = make_windows(datasets["ETHZMobil"], model.history).features[40]
    first, again = network.phi(window), network.phi(window + 0.1)
    assert not np.array_equal(first, again)  # each result is its own array, not overwritten
    np.testing.assert_array_equal(first, network.phi(window))
    # a NaN in the window reaches Φ, as in the training graph (no bound hides it)
    with np.errstate(invalid="ignore"):
        assert np.isnan(network.phi(np.full_like(window, np.nan))).all()


def test_compiled_networks_loaded_together_each_compute_their_own_phi(
    config, datasets, tmp_path
) -> None:
    """A run loads two networks (a learned plant, another internal model): each library's Φ
    calls its own GRU, whatever was loaded before it."""
    settings = _compile_settings(tmp_path)
    networks = []
    for i, variant in enumerate(("ddm-mish", "epm-gelu-layer-norm")):
        name, changes = SMALL[variant]
        spec = {**copy.deepcopy(config["models"][name]), **changes}
        save_network(tmp_path / f"{i}.npz", build_model(name, spec, TS, seed=i).network_arrays())
        networks.append(
            (load_network(tmp_path / f"{i}.npz", settings), load_network(tmp_path / f"{i}.npz"))
        )
    for compiled, uncompiled in networks + networks[::-1]:
        window = make_windows(datasets["ETHZMobil"], compiled.history).features[40]
        phi, ref = compiled.phi(window), uncompiled.phi(window)
        assert compiled.library is not None
        assert np.max(np.abs(phi - ref) / np.abs(ref).max()) <= 1e-5


def test_predicting_imports_neither_pytorch_nor_scipy(config, tmp_path) -> None:
    """A rollout process predicts Φ, compiled or not, without PyTorch or SciPy (GELU's erf
    included: importing ``scipy.special`` cost half a second in every EPM job)."""
    name, changes = SMALL["epm-gelu-layer-norm"]
    model = build_model(name, {**copy.deepcopy(config["models"][name]), **changes}, TS, seed=0)
    save_network(tmp_path / "network.npz", model.network_arrays())
    settings = _compile_settings(tmp_path)
    code = "\n".join(
        [
            "import json, sys, numpy as np",
            "from cape.models.network import load_network",
            f"for settings in (None, json.loads({json.dumps(settings)!r})):",
            f"    network = load_network({str(tmp_path / 'network.npz')!r}, settings)",
            "    network.phi(np.ones((network.history, 7)))",
            "    assert (network.library is None) == (settings is None)",
            "print(sorted(m for m in ('torch', 'scipy') if m in sys.modules))",
        ]
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_the_compiled_phi_is_built_once_then_loaded_from_the_cache(
    config, datasets, tmp_path, monkeypatch
) -> None:
    name, changes = SMALL["epm-gelu-layer-norm"]
    model = build_model(name, {**copy.deepcopy(config["models"][name]), **changes}, TS, seed=0)
    save_network(tmp_path / "network.npz", model.network_arrays())
    settings = _compile_settings(tmp_path)
    window = make_windows(datasets["ETHZMobil"], model.history).features[40]
    first = load_network(tmp_path / "network.npz", settings)
    phi = first.phi(window)
    library = first.library
    assert library is not None and library.with_name(library.name + ".sha256").is_file()

    def unbuilt(self: NumpyNetwork, name: str = "") -> None:
        raise AssertionError("the cached library was not used")

    monkeypatch.setattr(NumpyNetwork, "front_function", unbuilt)  # a cache hit builds nothing
    cached = load_network(tmp_path / "network.npz", settings)
    np.testing.assert_array_equal(cached.phi(window), phi)
    assert cached.library == library
