"""Plants (SPEC §5.1): learned, fixed-parameter and ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from cape.closedloop.disturbances import ParameterMismatch
from cape.closedloop.plants import FixedParameterPlant, LearnedPlant, TruthPlant, advance_pose
from cape.models.trained import TrainedModel
from cape.training.loop import build_model
from cape.vehicle import GROUND_TRUTH, state_derivative

TS = 0.02
GT = GROUND_TRUTH.as_dict()
TRUE_PHI = {**GT, "h": 0.0, "tau_delta": TS, "tau_T": TS}


class _TruePredictor:
    """Stands in for the network: Φ = the truth, and records the windows it is shown."""

    def __init__(self, model) -> None:
        self.row = np.array([TRUE_PHI[n] for n in model.param_names])
        self.windows: list[np.ndarray] = []

    def phi(self, window: np.ndarray) -> np.ndarray:
        self.windows.append(window.copy())
        return self.row


@pytest.fixture()
def epm(config):
    return build_model("epm", config["models"]["epm"], TS, seed=0)


def test_truth_plant_drives_straight_at_constant_speed() -> None:
    p = GROUND_TRUTH.replace(Shf=0.0, Svf=0.0, Shr=0.0, Svr=0.0).as_dict()
    vx = 1.5
    throttle = (p["Cr0"] + p["Cr2"] * vx**2) / (p["Cm1"] - p["Cm2"] * vx)  # Frx = 0
    plant = TruthPlant(p, TS)
    plant.reset(np.array([0.0, 0.0, 0.3, vx, 0.0, 0.0]))
    for _ in range(50):
        x = plant.step(np.array([throttle, 0.0]))
    np.testing.assert_allclose(
        x, [50 * TS * vx * np.cos(0.3), 50 * TS * vx * np.sin(0.3), 0.3, vx, 0, 0], atol=1e-12
    )


def test_learned_plant_window_and_step(epm) -> None:
    plant = LearnedPlant(TrainedModel(epm.physics, _TruePredictor(epm)))
    x0 = np.array([1.2, 0.9, 0.0, 1.0, 0.0, 0.0])
    plant.reset(x0)
    np.testing.assert_array_equal(plant.window, np.tile([1.0, 0, 0, 0, 0, 0, 0], (7, 1)))
    u0, u1 = np.array([0.3, 0.05]), np.array([0.4, 0.02])
    x1 = plant.step(u0)
    np.testing.assert_array_equal(plant.predictor.windows[0][-1], [1.0, 0, 0, 0, 0, 0.3, 0.05])
    # Euler step of the velocities with the true parameters (no lag: τ = Ts), mid-step heading
    v = x0[3:] + TS * state_derivative(x0, u0, GT)[3:]
    np.testing.assert_allclose(x1, advance_pose(x0, tuple(v), TS), rtol=1e-13)
    plant.step(u1)
    last = plant.predictor.windows[1][-1]
    np.testing.assert_allclose(last, [*x1[3:], 0.3, 0.05, 0.1, -0.03], rtol=1e-13)


def test_fixed_plant_equals_learned_plant_with_the_same_parameters(epm) -> None:
    learned = LearnedPlant(TrainedModel(epm.physics, _TruePredictor(epm)))
    fixed = FixedParameterPlant(epm.physics, {n: TRUE_PHI[n] for n in epm.param_names})
    x0 = np.array([0.0, 0.0, 0.5, 1.0, 0.0, 0.0])
    learned.reset(x0)
    fixed.reset(x0)
    rng = np.random.default_rng(0)
    for _ in range(100):
        u = np.array([rng.uniform(0, 0.6), rng.uniform(-0.3, 0.3)])
        np.testing.assert_array_equal(learned.step(u), fixed.step(u))


def test_dpm_fixed_plant_uses_the_drivetrain_law(config) -> None:
    dpm = build_model("dpm", config["models"]["dpm"], TS, seed=0)
    frozen = {
        n: GT[n]
        for n in ("Bf", "Cf", "Df", "Ef", "Br", "Cr", "Dr", "Er", "Cm1", "Cm2", "Cr0", "Cr2")
    }
    plant = FixedParameterPlant(dpm.physics, frozen)
    speeds = []
    for throttle in (0.0, 1.0):
        plant.reset(np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0]))
        speeds.append(plant.step(np.array([throttle, 0.0]))[3])
    slow, fast = speeds
    assert fast > 1.0 > slow  # the throttle acts through Cm1, Cm2


def test_mismatch_changes_the_plant_only(epm) -> None:
    mismatch = ParameterMismatch({"m": 1.05, "Bf": 0.95, "Br": 1.05, "Df": 0.9, "Dr": 0.9})
    frozen = {n: TRUE_PHI[n] for n in epm.param_names}
    nominal, changed = (
        FixedParameterPlant(epm.physics, frozen),
        FixedParameterPlant(epm.physics, frozen, mismatch.apply),
    )
    assert changed.params["m"] == pytest.approx(GT["m"] * 1.05) and nominal.params["m"] == GT["m"]
    x0 = np.array([0.0, 0.0, 0.0, 2.0, 0.1, 1.0])
    nominal.reset(x0)
    changed.reset(x0)
    assert not np.allclose(nominal.step(np.array([0.3, 0.2])), changed.step(np.array([0.3, 0.2])))
    truth = TruthPlant(GT, TS, mismatch.apply)
    assert truth.params["Df"] == pytest.approx(0.9 * GT["Df"]) and GT["Df"] == GROUND_TRUTH.Df
