"""Each training draw drives disturbance seeds of its own (SPEC §8, §10 revision 7): draw r's
seeds are r·study.seed_stride + 0 … S − 1, the same for every study, model, plant and
controller of the draw, disjoint from every other draw's; draw 0 keeps 0 … S − 1, so the default
target's runs are the ones the grid named before. The question's stages follow the same rule."""

from __future__ import annotations

import copy
import itertools
from collections import defaultdict
from collections.abc import Callable, Mapping
from typing import Any

import pytest
import yaml

from cape.config import REPO_ROOT, load_config, schema_default, validate_config
from cape.controllers import controller_class
from cape.errors import CapeError
from cape.layout.names import NMPCS
from cape.layout.runs import RunId
from cape.specs.study import StudySpec
from cape.study.grid import canonical, count_runs, study_grid, study_runs
from cape.study.question.plan import Plan, QuestionSettings, run_overrides, stage_runs

STRIDE = 1000
"""The schema's default ``study.seed_stride``."""


def _merge(into: dict[str, Any], other: Mapping[str, Any]) -> dict[str, Any]:
    """``other`` merged over ``into`` as Snakemake merges --configfile (mappings key by key)."""
    for key, value in other.items():
        if isinstance(value, Mapping) and isinstance(into.get(key), dict):
            _merge(into[key], value)
        else:
            into[key] = copy.deepcopy(value)
    return into


def _raw(*names: str) -> dict[str, Any]:
    """config/config.yaml with the named overlays merged over it, not yet validated."""
    config: dict[str, Any] = {}
    for name in ("config.yaml", *names):
        _merge(config, yaml.safe_load((REPO_ROOT / "config" / name).read_text()))
    return config


def _smoke(replicates: int | None = None) -> dict[str, Any]:
    """The smoke config (``--configfile config/smoke.yaml``), validated; ``replicates``: with
    that many training draws instead of its two."""
    config = _raw("smoke.yaml")
    if replicates is not None:
        config["training"]["replicates"] = replicates
    return validate_config(config, "smoke")


CONFIGS: dict[str, Callable[[], dict[str, Any]]] = {
    "default": load_config,
    "smoke": _smoke,
    "smoke, 3 draws": lambda: _smoke(3),
}


@pytest.fixture(scope="module", params=list(CONFIGS))
def config(request: pytest.FixtureRequest) -> dict[str, Any]:
    return CONFIGS[request.param]()


def _uses_internal(spec: StudySpec) -> Callable[[str], bool]:
    def uses(name: str) -> bool:
        return bool(controller_class(name, spec.controllers[name]).needs_internal_model)

    return uses


def _old_draw_zero(spec: StudySpec, uses_internal: Callable[[str], bool]) -> list[RunId]:
    """Draw 0's runs as the grid listed them before revision 7 (every draw on 0 … S − 1)."""
    runs = []
    for study, grid in spec.studies.items():
        if 0 not in grid.draws(spec.replicates):
            continue
        for plant, controller in itertools.product(grid.plants, grid.controllers):
            internals = (grid.internal or (plant,)) if uses_internal(controller) else (plant,)
            for internal, eta in itertools.product(internals, spec.etas_of(grid)):
                runs += [
                    RunId(study, plant, internal, controller, eta, s) for s in range(spec.seeds)
                ]
    return runs


def _seeds_by_cell(runs: list[RunId]) -> dict[tuple, set[int]]:
    """(study, plant, internal, controller, η, draw) → the cell's seeds."""
    cells: dict[tuple, set[int]] = defaultdict(set)
    for r in runs:
        cells[(r.study, r.plant, r.internal, r.controller, r.eta, r.replicate)].add(r.seed)
    return cells


def _draws_own_their_seeds(runs: list[RunId], expected: Callable[[int], range]) -> None:
    """Every cell of draw r has exactly ``expected(r)``, its first seed r·stride; the draws'
    seed sets are pairwise disjoint."""
    by_draw: dict[int, set[int]] = defaultdict(set)
    for cell, seeds in _seeds_by_cell(runs).items():
        replicate = cell[-1]
        assert seeds == set(expected(replicate)), cell  # the same for every model of the draw
        assert min(seeds) == replicate * STRIDE, cell
        by_draw[replicate] |= seeds
    for a, b in itertools.combinations(sorted(by_draw), 2):
        assert not by_draw[a] & by_draw[b], (a, b)


def test_the_stride_is_the_schemas_default() -> None:
    assert schema_default("study.seed_stride") == STRIDE
    assert load_config()["study"]["seed_stride"] == STRIDE  # filled in by validation
    # sections validated without their defaults (a --config-json) get the schema's
    bare = {"study": {"seeds": 2, "studies": {}}, "controllers": {}, "disturbances": {},
            "training": {}}  # fmt: skip
    spec = StudySpec.from_config(bare)
    assert spec.seed_stride == STRIDE and spec.draw_seeds(2) == range(2000, 2002)
    assert spec.draw_seeds(0) == range(2) and spec.draw_seeds(3, 1) == range(3000, 3001)
    with pytest.raises(ValueError, match=r"exceed `study\.seed_stride`"):
        spec.draw_seeds(1, STRIDE + 1)


def test_every_draw_runs_seeds_of_its_own(config: dict[str, Any]) -> None:
    """For every study and model: draws 0, 1 (and 2) on disjoint seeds, the same for every
    model, plant and controller of a draw, draw r's from r·stride."""
    spec = StudySpec.from_config(config)
    runs = list(study_grid(spec))
    assert {r.replicate for r in runs} == set(range(spec.replicates))
    _draws_own_their_seeds(runs, spec.draw_seeds)
    draw_one = {r.seed for r in runs if r.replicate == 1}
    assert draw_one == set(range(STRIDE, STRIDE + spec.seeds))


def test_draw_zero_keeps_the_runs_it_had(config: dict[str, Any]) -> None:
    """Draw 0's runs, their order and where each is computed are those of the grid before
    revision 7: the default target (the paper's tables) is unchanged."""
    spec = StudySpec.from_config(config)
    uses = _uses_internal(spec)
    runs = study_runs(spec, uses)
    old = _old_draw_zero(spec, uses)
    assert [r for r in runs if r.replicate == 0] == old
    grid = study_grid(spec)
    assert {r: c for r, c in grid.items() if r.replicate == 0} == canonical(old)


def test_the_count_is_the_listing(config: dict[str, Any]) -> None:
    spec = StudySpec.from_config(config)
    uses = _uses_internal(spec)
    assert count_runs(spec, uses) == len(study_runs(spec, uses))


def test_no_run_is_shared_between_draws(config: dict[str, Any]) -> None:
    """A run without a trained model (the ground-truth plant under its true model) was draw
    0's for every draw; on each draw's own seeds it is the draw's own, in its own folder."""
    spec = StudySpec.from_config(config)
    grid = study_grid(spec)
    assert all(computed.replicate == run.replicate for run, computed in grid.items())
    ceiling = [r for r in grid if not r.uses_trained_model() and r.replicate == 1]
    assert ceiling and all(grid[r] == r and r.seed >= STRIDE for r in ceiling)


def test_the_default_grids_counts_by_hand() -> None:
    """The default config: 5880 runs listed; draw 0 computes 2600 (the ablation's diagonal, 90,
    is the learned study's); draws 1 and 2 compute all their 825 + 770 each (before revision 7,
    1320: the truth study's 275 runs without a learned model were draw 0's)."""
    grid = study_grid(StudySpec.from_config(load_config()))
    computed = set(grid.values())
    per_draw = {r: sum(c.replicate == r for c in computed) for r in range(3)}
    assert len(grid) == 5880 and per_draw == {0: 2600, 1: 1595, 2: 1595}


@pytest.mark.parametrize("draws", [3, 6])
def test_a_question_stage_runs_each_draw_on_its_own_seeds(draws: int) -> None:
    """The question's stage (draws 0–2 with 5 seeds, later draws 4): each draw's seeds start at
    r·stride, are shared by the models and NMPCs of the draw and by no other draw, and are
    the grid's own runs once the stage's overrides are merged."""
    config = load_config()
    settings = QuestionSettings.from_config(config)
    assert settings.seed_stride == STRIDE
    plan = Plan({m: draws for m in settings.models}, (5, 5, 5) + (4,) * (draws - 3))
    runs = stage_runs(settings, plan)
    assert {r.controller for r in runs} == set(NMPCS)
    assert {r.internal for r in runs} == set(settings.models)
    _draws_own_their_seeds(runs, lambda r: range(r * STRIDE, r * STRIDE + plan.seeds_of(r)))
    assert {r.replicate for r in runs} == set(range(draws))
    assert len(runs) == len(settings.models) * len(NMPCS) * len(settings.etas) * sum(
        plan.seeds_of(r) for r in range(draws)
    )
    overrides = run_overrides(StudySpec.from_config(config), settings, plan)
    staged = _merge(copy.deepcopy(config), overrides)
    grid = study_grid(StudySpec.from_config(validate_config(staged, "stage")))
    assert set(runs) <= set(grid)
    assert all(grid[r] == r for r in runs)  # each computed in its own folder


def test_a_question_setting_without_its_stride_has_the_schemas() -> None:
    settings = QuestionSettings(("a", "b"), (3, 6), 0.05, 2.0, {}, "truth", ("0",), 5, 2)
    assert settings.seed_stride == STRIDE
    assert settings.draw_seeds(2, 4) == range(2000, 2004)
    with pytest.raises(ValueError, match=r"exceed `study\.seed_stride`"):
        settings.draw_seeds(0, STRIDE + 1)


@pytest.mark.parametrize(
    ("change", "key"),
    [
        ({"study": {"seeds": 5, "seed_stride": 4}}, "study.seeds"),
        ({"study": {"seeds": 1, "seed_stride": 1},
          "question": {"plan": {"draws": {"epm": 3, "ddm": 3}, "seeds": [1, 1, 1, 2]}}},
         "question.plan.seeds"),
    ],
)  # fmt: skip
def test_seeds_beyond_the_stride_are_refused(change: dict, key: str) -> None:
    """More seeds per draw than the stride would make draw r's reach draw r + 1's: one line
    naming both keys and the fix."""
    config = _merge(_raw(), change)
    with pytest.raises(CapeError) as refused:
        validate_config(config, "config")
    message = str(refused.value)
    assert f"`{key}`" in message and "`study.seed_stride`" in message and "\n" not in message
    assert "raise `study.seed_stride`" in message
    fine = _merge(_raw(), {"study": {"seeds": 5, "seed_stride": 5}})
    assert validate_config(fine, "config")["study"]["seed_stride"] == 5


def test_a_stride_of_its_own_moves_the_later_draws_only() -> None:
    config = load_config()
    config["study"]["seed_stride"] = 10
    spec = StudySpec.from_config(config)
    runs = list(study_grid(spec))
    assert {r.seed for r in runs if r.replicate == 0} == set(range(5))
    assert {r.seed for r in runs if r.replicate == 2} == set(range(20, 25))
