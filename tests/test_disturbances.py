"""The η disturbance pipeline (SPEC §6): each source alone, and η = 0 corrupting nothing."""

from __future__ import annotations

import numpy as np
import pytest

from cape.closedloop.disturbances import (
    SOURCES,
    Crosswind,
    DisturbancePipeline,
    ImuBias,
    MeasurementNoise,
    ParameterMismatch,
    ProcessNoise,
    SteeringDelay,
)
from cape.specs.run import DisturbancesSpec
from cape.vehicle import GROUND_TRUTH

X = np.array([1.0, -0.5, 0.3, 2.0, 0.1, -1.5])


def test_measurement_noise_has_the_stated_relative_sigma(config) -> None:
    """σ = η/100 relative, plus the 1e-4 floor: checked on 20 000 draws at η = 2."""
    pipe = DisturbancePipeline.from_config(config["disturbances"], eta=2.0, seed=1)
    assert pipe.noise is not None and pipe.noise.sigma == pytest.approx(0.02)
    rng = np.random.default_rng(0)
    draws = np.array([pipe.noise.apply(X, rng) for _ in range(20000)])
    expected = 0.02 * np.abs(X) + 1e-4
    np.testing.assert_allclose(draws.std(axis=0), expected, rtol=0.03)
    assert np.all(np.abs(draws.mean(axis=0) - X) < 4 * expected / np.sqrt(20000))  # unbiased


def test_heading_noise_does_not_grow_with_the_number_of_turns() -> None:
    """SPEC §6: the heading's noise is scaled by the wrapped heading, so it is the same at ψ and
    ψ − 2π (one more turn), and small near ψ = 2π; unwrapped (``wrap_heading: False``) it grows."""
    noise = MeasurementNoise(sigma=0.05, floor=np.full(6, 1e-4))
    unwrapped = MeasurementNoise(sigma=0.05, floor=np.full(6, 1e-4), wrap_heading=False)

    def heading_std(source: MeasurementNoise, psi: float) -> float:
        rng = np.random.default_rng(4)
        y = X.copy()
        y[2] = psi
        return float(np.std([source.apply(y, rng)[2] - psi for _ in range(20000)]))

    psi = 0.8
    once, twice = heading_std(noise, psi), heading_std(noise, psi - 2 * np.pi)
    assert once == pytest.approx(0.05 * 0.8 + 1e-4, rel=0.03)
    assert twice == pytest.approx(once, rel=1e-9)  # the same draws, the same scale
    assert heading_std(noise, 2 * np.pi - 0.01) == pytest.approx(0.05 * 0.01 + 1e-4, rel=0.03)
    # the unwrapped scale counts turns: |0.8 − 2π| / 0.8 ≈ 6.9× larger one turn later
    assert heading_std(unwrapped, psi - 2 * np.pi) > 6 * once
    # the noise is added to the car's own unwrapped heading
    y = X.copy()
    y[2] = psi - 4 * np.pi
    assert abs(noise.apply(y, np.random.default_rng(0))[2] - y[2]) < 0.5


def test_process_noise_touches_only_the_velocities_with_2_eta_percent() -> None:
    noise = ProcessNoise(sigma=2 * 1.5 / 100, floor=1e-4)
    rng = np.random.default_rng(0)
    draws = np.array([noise.apply(X, rng) for _ in range(20000)])
    np.testing.assert_array_equal(draws[:, :3], np.tile(X[:3], (20000, 1)))
    np.testing.assert_allclose(draws[:, 3:].std(axis=0), 0.03 * np.abs(X[3:]) + 1e-4, rtol=0.03)


def test_steering_delay_shifts_by_exactly_one_step() -> None:
    delay = SteeringDelay(steps=1)
    delay.reset(0.0)
    commands = [0.1, -0.2, 0.3, 0.05]
    applied = [delay.apply(c) for c in commands]
    assert applied == [0.0, 0.1, -0.2, 0.3]
    pipe = DisturbancePipeline(eta=1.0, rng=np.random.default_rng(0), delay=SteeringDelay(1))
    pipe.reset(delta0=0.02)
    np.testing.assert_array_equal(
        pipe.actuate(np.array([0.5, 0.1])), [0.5, 0.02]
    )  # throttle on time
    np.testing.assert_array_equal(pipe.actuate(np.array([0.4, -0.1])), [0.4, 0.1])


def test_imu_bias_is_a_random_walk_on_heading_and_yaw_rate() -> None:
    bias = ImuBias(sigma_psi=2e-4, sigma_omega=2e-3)
    rng = np.random.default_rng(3)
    finals = []
    for _ in range(2000):
        bias.reset()
        for _ in range(100):
            z = bias.apply(X, rng)
        finals.append(z - X)
    finals = np.array(finals)
    np.testing.assert_array_equal(finals[:, [0, 1, 3, 4]], 0.0)
    # after n steps a random walk has σ·√n
    np.testing.assert_allclose(finals[:, [2, 5]].std(axis=0), [2e-4 * 10, 2e-3 * 10], rtol=0.06)


def test_crosswind_scales_with_speed_and_yaw_rate() -> None:
    wind = Crosswind(vy_gain=0.02, vx_floor=0.01, omega_gain=0.02, omega_floor=0.1)
    rng = np.random.default_rng(5)
    draws = np.array([wind.apply(X, rng) for _ in range(20000)])
    np.testing.assert_allclose(draws[:, 4].std(), 0.02 * 2.0, rtol=0.03)
    np.testing.assert_allclose(draws[:, 5].std(), 0.02 * 1.5, rtol=0.03)
    slow = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    draws = np.array([wind.apply(slow, rng) for _ in range(20000)])
    np.testing.assert_allclose(draws[:, [4, 5]].std(axis=0), [0.02 * 0.01, 0.02 * 0.1], rtol=0.03)


def test_mismatch_scales_exactly_the_four_quantities(config) -> None:
    mismatch = DisturbancePipeline.from_config(config["disturbances"], eta=1.0, seed=0).mismatch
    assert isinstance(mismatch, ParameterMismatch)
    true = GROUND_TRUTH.as_dict()
    plant = mismatch.apply(true)
    changed = {k for k in true if plant[k] != true[k]}
    assert changed == {"m", "Bf", "Br", "Df", "Dr"}  # mass, front and rear stiffness, friction
    assert plant["m"] == pytest.approx(true["m"] * 1.05)
    assert plant["Bf"] == pytest.approx(true["Bf"] * 0.95) and plant["Br"] == pytest.approx(
        true["Br"] * 1.05
    )
    assert plant["Df"] == pytest.approx(true["Df"] * 0.90) and plant["Dr"] == pytest.approx(
        true["Dr"] * 0.90
    )


def test_eta_zero_corrupts_nothing_and_draws_nothing(config) -> None:
    pipe = DisturbancePipeline.from_config(config["disturbances"], eta=0.0, seed=123)
    assert pipe.active_sources() == []
    state = pipe.rng.bit_generator.state
    pipe.reset(0.1)
    np.testing.assert_array_equal(pipe.actuate(np.array([0.3, 0.2])), [0.3, 0.2])
    np.testing.assert_array_equal(pipe.after_plant(X), X)
    np.testing.assert_array_equal(pipe.measure(X), X)
    assert pipe.plant_params(GROUND_TRUTH.as_dict()) == GROUND_TRUTH.as_dict()
    assert pipe.rng.bit_generator.state == state


def test_every_source_is_active_above_zero_and_runs_repeat(config) -> None:
    def run(seed: int) -> np.ndarray:
        pipe = DisturbancePipeline.from_config(config["disturbances"], eta=2.0, seed=seed)
        pipe.reset(0.0)
        out = []
        x = X
        for _ in range(20):
            x = pipe.after_plant(x)
            out.append(pipe.measure(x))
        return np.array(out)

    pipe = DisturbancePipeline.from_config(config["disturbances"], eta=0.5, seed=0)
    assert pipe.active_sources() == list(SOURCES)  # every one, in their fixed order
    np.testing.assert_array_equal(run(7), run(7))
    assert not np.array_equal(run(7), run(8))
    with pytest.raises(ValueError, match="η must be ≥ 0"):
        DisturbancePipeline.from_config(config["disturbances"], eta=-1.0, seed=0)


def test_measurement_noise_floor_applies_at_zero() -> None:
    noise = MeasurementNoise(sigma=0.05, floor=np.full(6, 1e-4))
    draws = np.array([noise.apply(np.zeros(6), np.random.default_rng(i)) for i in range(5000)])
    np.testing.assert_allclose(draws.std(axis=0), 1e-4, rtol=0.05)


# --- a source added by a module and a config entry (examples/throttle_delay.py) -----------


def _with_throttle_delay(config, **entry) -> dict:
    settings = {"module": "examples/throttle_delay.py", "active_from": 0, "steps": 2, **entry}
    return {**config["disturbances"], "throttle_delay": settings}


def _as_spec(disturbances: dict) -> DisturbancesSpec:
    return DisturbancesSpec.from_config({"disturbances": disturbances})


def test_a_plugged_in_source_acts_after_the_six_and_delays_the_throttle(config) -> None:
    disturbances = _with_throttle_delay(config)
    pipe = DisturbancePipeline.from_config(disturbances, eta=1.0, seed=0)
    assert pipe.active_sources() == [*SOURCES, "throttle_delay"]
    pipe.reset(0.0)
    applied = [pipe.actuate(np.array([t, 0.0]))[0] for t in (0.1, 0.2, 0.3, 0.4)]
    assert applied == [0.0, 0.0, 0.1, 0.2]  # two samples late, released at the start
    quiet = DisturbancePipeline.from_config(disturbances, eta=0.0, seed=0)
    assert quiet.active_sources() == []  # η = 0 still corrupts nothing


def test_table_3_and_the_block_diagram_list_a_plugged_in_source(config) -> None:
    from cape.study.reports.tables import uncertainty_activation

    table = uncertainty_activation(_as_spec(_with_throttle_delay(config, active_from=1.5)))
    column = table.set_index("η")["throttle delay (steps)"]
    assert column["1"] == "–" and column["2"] == "2" and column["5"] == "2"
    assert list(table.columns)[-1] == "throttle delay (steps)"  # after SPEC §6's six

    import matplotlib

    matplotlib.use("Agg")
    from cape.plots.study import block_diagram

    fig = block_diagram(_as_spec(_with_throttle_delay(config)))
    texts = [t.get_text() for t in fig.axes[0].texts]
    actuation = next(t for t in texts if "steering delay" in t)
    assert "throttle delay" in actuation  # in the actuators' box, beside the steering delay


def test_a_bad_source_entry_is_named_with_its_key(config) -> None:
    from cape.closedloop.disturbances import validate_sources
    from cape.errors import CapeError

    with pytest.raises(CapeError, match=r"disturbances\.throttle_delay\.steps"):
        validate_sources(_with_throttle_delay(config, steps=-1), "config/config.yaml")
    with pytest.raises(CapeError, match="throttle_delay"):
        validate_sources(_with_throttle_delay(config, stepz=2), "config/config.yaml")
    with pytest.raises(CapeError, match="gust"):  # no class of that name and no module
        validate_sources({**config["disturbances"], "gust": {"active_from": 0}})
