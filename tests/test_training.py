"""Training, checkpoints and the open-loop evaluation (SPEC §4, §4.4, §4.5)."""

from __future__ import annotations

import hashlib
import json
import re
import time
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from cape.cli import main
from cape.data.windows import make_windows
from cape.errors import CapeError
from cape.models.layers import gru_stages
from cape.specs.training import TrainingCompile
from cape.training.checkpoint import load_model, save_model
from cape.training.evaluate import count_flops, frozen_parameters, multistep_error, one_step_rmse
from cape.training.loop import (
    AdamStep,
    PaddedBatches,
    TrainingData,
    batch_loss,
    build_model,
    train_model,
)
from cape.vehicle import GROUND_TRUTH

TS = 0.02


@pytest.fixture(scope="module")
def small_data(datasets) -> dict[int, TrainingData]:
    """A small slice of the ETHZ windows per history length: enough to train for seconds."""
    out = {}
    for history in (5, 7, 10):
        full = TrainingData.from_dataset(datasets["ETHZ"], history, 0.9, seed=0)
        out[history] = TrainingData(
            full.train.subset(np.arange(96)), full.val.subset(np.arange(32)), full.scaler
        )
    return out


def _train(config, name: str, data: TrainingData, seed: int = 0, epochs: int = 2):
    return train_model(
        name, config["models"][name], data, ts=TS, seed=seed, epochs=epochs, progress=False
    )


@pytest.mark.parametrize("name", ["dpm", "ddm", "epm"])
def test_two_epochs_on_a_small_slice_run_in_seconds(config, small_data, name: str) -> None:
    spec = config["models"][name]
    start = time.perf_counter()
    result = _train(config, name, small_data[spec["history"]])
    assert time.perf_counter() - start < 20.0
    assert [r["epoch"] for r in result.losses] == [1, 2]
    assert all(np.isfinite(r["train_loss"]) and np.isfinite(r["val_loss"]) for r in result.losses)
    assert result.best_val_loss == min(r["val_loss"] for r in result.losses)


def test_fused_adam_follows_the_loop_adam_within_rounding(config, small_data) -> None:
    """The fused kernel is the same update up to rounding: losses within 1e-3 relative over the
    first epochs (issue 15: a faster kernel may change only the last digits)."""
    data = small_data[7]
    spec = config["models"]["epm"]
    fused = train_model("epm", spec, data, ts=TS, seed=0, epochs=8, progress=False, fused=True)
    loop = train_model("epm", spec, data, ts=TS, seed=0, epochs=8, progress=False, fused=False)
    for a, b in zip(fused.losses, loop.losses, strict=True):
        assert a["train_loss"] == pytest.approx(b["train_loss"], rel=1e-3)
        assert a["val_loss"] == pytest.approx(b["val_loss"], rel=1e-3)


GRU_SHAPES = [(7, 7, 7), (8, 10, 10), (7, 5, 5), (1, 4, 3), (3, 4, 1), (2, 3, 6)]


@pytest.mark.parametrize(("layers", "hidden", "steps"), GRU_SHAPES)
def test_the_gru_stage_by_stage_is_the_gru(layers: int, hidden: int, steps: int) -> None:
    """The training graph's GRU (anti-diagonal stages) is nn.GRU's: outputs and gradients
    agree to float32 rounding for deep and shallow stacks, long and short windows."""
    torch.manual_seed(0)
    gru = torch.nn.GRU(7, hidden, layers, batch_first=True)
    x = torch.randn(16, steps, 7)
    reference, staged = gru(x)[0], gru_stages(gru, x)
    torch.testing.assert_close(staged, reference, rtol=1e-5, atol=1e-6)
    weights = torch.randn_like(reference)
    expected = torch.autograd.grad((weights * reference).sum(), list(gru.parameters()))
    got = torch.autograd.grad((weights * staged).sum(), list(gru.parameters()))
    for a, b in zip(got, expected, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5 * float(b.abs().max()))


def test_padded_batches_keep_the_recipe_order_and_mask_the_padding() -> None:
    order = torch.randperm(37, generator=torch.Generator().manual_seed(0))
    batches = list(PaddedBatches(16).of(order))
    assert [size for *_, size in batches] == [16, 16, 5]
    assert torch.equal(torch.cat([index[:size] for index, *_, size in batches]), order)
    for index, mask, count, size in batches:
        assert len(index) == len(mask) == 16 and float(count) == size
        assert mask[:size].eq(1).all() and mask[size:].eq(0).all()


def test_a_padded_batch_has_the_loss_and_gradients_of_the_batch(config, small_data) -> None:
    """The rows that pad the last batch to full size change neither its loss (the MSE over its
    real rows) nor the gradients, up to the rounding of float32 products of another batch
    size."""
    data = small_data[7]
    model = build_model("epm", config["models"]["epm"], TS, seed=0)
    model.set_scaler(data.scaler.mean, data.scaler.scale)
    x, y = torch.as_tensor(data.train.features), torch.as_tensor(data.train.labels)
    index = torch.tensor([5, 3, 11, 2, 40])
    ((padded_index, mask, count, _),) = PaddedBatches(8).of(index)
    padded = batch_loss(model, x, y)(padded_index, mask, count)
    plain = torch.mean((model(x[index], stages=True) - y[index]) ** 2)
    assert float(padded) == pytest.approx(float(plain), rel=1e-6)
    params = list(model.parameters())
    for a, b in zip(torch.autograd.grad(padded, params), torch.autograd.grad(plain, params),
                    strict=True):  # fmt: skip
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-6 * float(b.abs().max()))


def test_adam_step_is_the_optimisers_step_bit_for_bit(config) -> None:
    """The step without Optimizer.step's bookkeeping is the same update: the same weights and
    the same optimiser state (so the same checkpoint) after several steps."""
    spec = config["models"]["dpm"]
    models = [build_model("dpm", spec, TS, seed=0) for _ in range(2)]
    optimisers = [torch.optim.Adam(m.parameters(), lr=1e-3, fused=True) for m in models]
    fast = AdamStep(optimisers[1])
    generator = torch.Generator().manual_seed(1)
    for _ in range(4):  # the first creates the state (the fallback), the others run fast
        for a, b in zip(models[0].parameters(), models[1].parameters(), strict=True):
            a.grad = torch.randn(a.shape, generator=generator)
            b.grad = a.grad.clone()
        optimisers[0].step()
        fast()
    for a, b in zip(models[0].state_dict().values(), models[1].state_dict().values(),
                    strict=True):  # fmt: skip
        assert torch.equal(a, b)
    state = [o.state_dict()["state"] for o in optimisers]
    assert state[0].keys() == state[1].keys()
    for key in state[0]:
        for name in ("step", "exp_avg", "exp_avg_sq"):
            assert torch.equal(state[0][key][name], state[1][key][name])


def test_adam_step_updates_each_weight_with_its_own_gradient_whatever_the_layout() -> None:
    """A gradient with its parameter's shape but transposed strides (as ``torch.autograd.grad``
    returns the GRU's weight gradients): the update is the for-loop Adam's, element by element.
    PyTorch's fused CPU kernel alone would read the gradient in memory order."""
    generator = torch.Generator().manual_seed(2)
    weights = [torch.randn(3, 5, generator=generator) for _ in range(2)]
    params = [torch.nn.Parameter(w.clone()) for w in weights]
    reference = [torch.nn.Parameter(w.clone()) for w in weights]
    fast = AdamStep(torch.optim.Adam(params, lr=0.1, fused=True))
    loop = torch.optim.Adam(reference, lr=0.1, foreach=False)
    for _ in range(3):  # the first creates the state (the fallback), the others run fast
        for p, r in zip(params, reference, strict=True):
            grad = torch.randn(5, 3, generator=generator)
            p.grad = grad.T  # shape (3, 5), strides (1, 3)
            r.grad = grad.T.contiguous()
        assert params[0].grad.stride() != params[0].stride()
        fast()
        loop.step()
        for p, r in zip(params, reference, strict=True):
            torch.testing.assert_close(p.detach(), r.detach(), rtol=1e-6, atol=1e-7)


@pytest.mark.slow  # a cold-cache compile: about a minute on two cores
def test_compiled_training_is_reproducible_and_follows_eager_training(
    config, small_data, tmp_path: Path
) -> None:
    """torch.compile'd steps (issues 15, 22), as the config compiles them (C++ wrapper): the
    same seed twice gives the same losses bit for bit, and the losses follow eager training
    within 1e-3 relative over the first 20 epochs (90 windows: two batches of 32 and a last one
    of 26, padded). A smaller GRU and trunk than EPM's keep the (cold-cache) compile short; the
    graph is the same kind."""
    head = {"width": 32, "layers": 2, "activation": "gelu", "layer_norm_after": [1]}
    spec = {**config["models"]["epm"], "gru": {"hidden": 7, "layers": 2}, "head": head}
    given = TrainingCompile.from_config(config)
    settings = TrainingCompile(given.enabled, given.cpp_wrapper, str(tmp_path / "inductor"))
    assert settings.enabled and settings.cpp_wrapper
    data = small_data[7]
    data = TrainingData(data.train.subset(np.arange(90)), data.val, data.scaler)

    def run(compile_settings):
        return train_model("epm", spec, data, ts=TS, seed=0, epochs=20, progress=False,
                           compile_settings=compile_settings)  # fmt: skip

    eager, first, second = run(None), run(settings), run(settings)
    assert first.losses == second.losses
    assert any((tmp_path / "inductor").iterdir())  # the cache is where the config says
    for a, b in zip(first.losses, eager.losses, strict=True):
        assert a["train_loss"] == pytest.approx(b["train_loss"], rel=1e-3)
        assert a["val_loss"] == pytest.approx(b["val_loss"], rel=1e-3)


def test_same_seed_same_losses_other_seed_other_weights(config, small_data) -> None:
    a = _train(config, "epm", small_data[7], seed=0)
    b = _train(config, "epm", small_data[7], seed=0)
    c = _train(config, "epm", small_data[7], seed=1)
    assert a.losses == b.losses  # bit for bit
    for key, value in a.model.state_dict().items():
        assert torch.equal(value, b.model.state_dict()[key])
    assert not torch.equal(a.model.gru.weight_ih_l0, c.model.gru.weight_ih_l0)
    assert a.losses != c.losses


def test_training_reduces_the_loss(config, small_data) -> None:
    result = _train(config, "ddm", small_data[5], epochs=6)
    assert result.losses[-1]["train_loss"] < 0.5 * result.losses[0]["train_loss"]


def test_best_validation_checkpoint_is_kept(config, small_data) -> None:
    result = _train(config, "dpm", small_data[10], epochs=4)
    best = min(result.losses, key=lambda r: r["val_loss"])
    assert result.best_epoch == best["epoch"]
    with torch.no_grad():
        val = small_data[10].val
        loss = torch.mean(
            (result.model(torch.as_tensor(val.features)) - torch.as_tensor(val.labels)) ** 2
        )
    assert float(loss) == pytest.approx(best["val_loss"], rel=1e-12)


def test_checkpoint_round_trip(config, small_data, tmp_path: Path) -> None:
    result = _train(config, "epm", small_data[7])
    save_model(result.model, tmp_path, {"seed": 0})
    loaded = load_model(tmp_path, expected_name="epm")
    x = torch.as_tensor(small_data[7].val.features)
    with torch.no_grad():
        assert torch.equal(loaded(x), result.model(x))
    assert json.loads((tmp_path / "meta.json").read_text())["param_names"][-1] == "tau_T"


def test_corrupt_or_mismatched_checkpoints_fail_clearly(config, small_data, tmp_path: Path) -> None:
    result = _train(config, "ddm", small_data[5], epochs=1)
    save_model(result.model, tmp_path, {})
    with pytest.raises(CapeError, match="holds model 'ddm', expected 'epm'"):
        load_model(tmp_path, expected_name="epm")
    # weights of another architecture: the config (meta.json) says 8 layers, the file has 16
    meta = json.loads((tmp_path / "meta.json").read_text())
    meta["spec"]["head"]["layers"] = 8
    (tmp_path / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(CapeError, match=r"does not match the ddm architecture.*retrain"):
        load_model(tmp_path)
    meta["spec"]["head"]["layers"] = 16
    meta["spec"]["head"]["width"] = 400
    (tmp_path / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(CapeError, match=r"has shape .* needs"):
        load_model(tmp_path)
    # a damaged weights file
    meta["spec"]["head"]["width"] = 436
    (tmp_path / "meta.json").write_text(json.dumps(meta))
    (tmp_path / "model.pt").write_bytes(b"this is not a checkpoint")
    with pytest.raises(CapeError, match=r"model.pt: does not match the checksum .* train it"):
        load_model(tmp_path)  # caught by the checksum of meta.json, before torch reads it
    meta["weights_sha256"] = hashlib.sha256(b"this is not a checkpoint").hexdigest()
    (tmp_path / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(CapeError, match=r"model.pt: not a readable checkpoint"):
        load_model(tmp_path)  # a file damaged before its checksum was taken: torch's error
    (tmp_path / "meta.json").write_text("{broken")
    with pytest.raises(CapeError, match=r"meta\.json: corrupt"):
        load_model(tmp_path)
    with pytest.raises(CapeError, match="missing; train the model first"):
        load_model(tmp_path / "nowhere")


def test_exported_network_round_trip_and_its_errors(config, small_data, tmp_path: Path) -> None:
    """What the closed loop loads: meta.json + network.npz, without PyTorch; a missing, damaged
    or mismatched export fails with the file and the fix."""
    import numpy as np

    from cape.models.trained import load_trained
    from cape.training.checkpoint import export_network

    result = _train(config, "epm", small_data[7], epochs=1)
    save_model(result.model, tmp_path, {})
    with pytest.raises(CapeError, match=r"network\.npz: missing; rebuild it with `snakemake"):
        load_trained(tmp_path, "epm")
    export_network(tmp_path)
    trained = load_trained(tmp_path, "epm")
    window = small_data[7].val.features[0]
    with torch.no_grad():
        ref = result.model(torch.as_tensor(window[None]))[0].numpy()
    np.testing.assert_allclose(trained.predict(window), ref, rtol=1e-6, atol=1e-9)
    with pytest.raises(CapeError, match="holds model 'epm', expected 'ddm'"):
        load_trained(tmp_path, "ddm")
    meta = json.loads((tmp_path / "meta.json").read_text())
    meta["spec"]["history"] = 9
    (tmp_path / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(CapeError, match=r"built for windows of 7 rows .* has 9"):
        load_trained(tmp_path, "epm")
    (tmp_path / "network.npz").write_bytes(b"not an npz")
    with pytest.raises(CapeError, match=r"network\.npz: not a readable network"):
        load_trained(tmp_path, "epm")


class _TruePhi:
    """Stand-in network output: the ground-truth Φ for every window."""

    def __init__(self, model) -> None:
        values = {**GROUND_TRUTH.as_dict(), "h": 0.0, "tau_delta": TS, "tau_T": TS}
        self.phi_row = torch.tensor([values[n] for n in model.param_names], dtype=torch.float64)

    def __call__(self, windows: torch.Tensor) -> torch.Tensor:
        return self.phi_row.expand(windows.shape[0], -1)


def test_evaluation_of_a_perfect_model_is_exact(config, datasets) -> None:
    """With Φ = truth the DDM is the data-generating model: every error is rounding."""
    from cape.training.loop import build_model

    model = build_model("ddm", config["models"]["ddm"], TS, seed=0)
    model.phi = _TruePhi(model)  # type: ignore[method-assign]
    test = make_windows(datasets["ETHZMobil"], 5)
    assert max(one_step_rmse(model, test).values()) < 1e-12
    assert max(multistep_error(model, datasets["ETHZMobil"], horizon=15).values()) < 1e-10


def test_multistep_with_horizon_one_is_the_one_step_error(config, small_data, datasets) -> None:
    result = _train(config, "epm", small_data[7], epochs=1)
    test = make_windows(datasets["ETHZMobil"], 7)
    one = multistep_error(result.model, datasets["ETHZMobil"], horizon=1)
    with torch.no_grad():
        err = np.abs(result.model(torch.as_tensor(test.features)).numpy() - test.labels)
    # horizon 1 uses every window whose label exists: one more than make_windows keeps
    np.testing.assert_allclose([one["vx"], one["vy"], one["omega"]], err.mean(axis=0), rtol=2e-3)
    assert multistep_error(result.model, datasets["ETHZMobil"], horizon=15)["vx"] > one["vx"]


def test_frozen_parameters_are_medians(config, small_data) -> None:
    dpm = _train(config, "dpm", small_data[10], epochs=1).model
    frozen = frozen_parameters(dpm, small_data[10].train)
    with torch.no_grad():
        phi = dpm.phi(torch.as_tensor(small_data[10].train.features)).numpy()
    assert frozen["Bf"] == pytest.approx(float(np.median(phi[:, 0])))
    assert (
        "Frx" not in frozen
        and frozen["Cm1"] == GROUND_TRUTH.Cm1
        and frozen["Cr2"] == GROUND_TRUTH.Cr2
    )


def test_flops_are_counted(config) -> None:
    from cape.training.loop import build_model

    ddm = build_model("ddm", config["models"]["ddm"], TS, seed=0)
    flops = count_flops(ddm, np.zeros((5, 7)))
    linear_macs = sum(
        m.in_features * m.out_features for m in ddm.modules() if isinstance(m, torch.nn.Linear)
    )
    assert flops >= 2 * linear_macs  # 2 FLOPs per multiply-accumulate, plus the GRU's


def test_cli_train_writes_a_complete_model_folder(config, datasets, tmp_path: Path) -> None:
    data = tmp_path / "ethz.npz"
    np.savez(data, **datasets["ETHZ"])
    out = tmp_path / "epm"
    # eager: a compiled step is the slow test's (a cold compile takes minutes), and the compile
    # cache would land under the repository's results/
    eager = {**config, "training": {**config["training"], "compile": {"enabled": False}}}
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(eager))
    argv = ["train", "--model", "epm", "--data", str(data), "--out", str(out), "--epochs", "1",
            "--config", str(tmp_path / "config.yaml")]  # fmt: skip
    assert main(argv) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names[1:] == ["loss.csv", "meta.json", "model.pt"]  # and the kept checkpoint:
    assert re.fullmatch(r"checkpoint-[0-9a-f]{16}\.pt", names[0]), names
    meta = json.loads((out / "meta.json").read_text())
    assert meta["epochs"] == 1 and meta["seed"] == 0 and len(meta["data_sha256"]) == 64
    assert meta["compiled"] is False
    assert (out / "loss.csv").read_text().splitlines()[0] == "epoch,train_loss,val_loss"
    assert isinstance(load_model(out, "epm"), torch.nn.Module)


def test_cli_train_unknown_model_is_clear(tmp_path: Path, capsys) -> None:
    assert main(["train", "--model", "gpt", "--data", "x.npz", "--out", str(tmp_path)]) == 2
    assert "--model gpt: not in the config's `models`" in capsys.readouterr().err


def test_compiled_training_without_a_compiler_says_how_to_train_eagerly(
    config, small_data, tmp_path: Path, monkeypatch
) -> None:
    import torch._inductor.config as inductor

    monkeypatch.setattr(inductor.cpp, "cxx", (str(tmp_path / "no-such-g++"),))
    settings = TrainingCompile(True, False, str(tmp_path / "inductor"))  # cold: it must compile
    with pytest.raises(CapeError, match=r"training\.compile\.enabled: false"):
        train_model("dpm", config["models"]["dpm"], small_data[10], ts=TS, seed=0, epochs=1,
                    progress=False, compile_settings=settings)  # fmt: skip


def test_a_failed_compile_names_its_likely_cause(monkeypatch: pytest.MonkeyPatch) -> None:
    from cape.training.loop import _compile_error

    monkeypatch.delenv("ATEN_CPU_CAPABILITY", raising=False)
    missing = str(_compile_error(RuntimeError("no compiler found"), missing_compiler=True))
    assert "needs a C++ compiler" in missing and "training.compile.enabled: false" in missing
    monkeypatch.setenv("ATEN_CPU_CAPABILITY", "default")
    forced = str(_compile_error(RuntimeError("vectorisation failed\nmore")))
    assert "ATEN_CPU_CAPABILITY=default is set" in forced and "C++ compiler (" not in forced
    assert "vectorisation failed" in forced and "more" not in forced  # the first line only
    assert "training.compile.enabled: false" in forced


def test_a_damaged_training_record_is_named_with_its_fix(
    config, small_data, tmp_path: Path
) -> None:
    """loss.csv empty or without its columns, best_val_loss null, a checkpoint of this training
    that lacks a key: one CapeError naming the file, never pandas' or torch's own."""
    from cape.models.trained import read_training
    from cape.training.loop import Checkpointing

    result = _train(config, "dpm", small_data[10], epochs=1)
    save_model(result.model, tmp_path, {"best_val_loss": 1e-3, "best_epoch": 1},
               {"loss.csv": b"epoch,train_loss,val_loss\n1,0.5,0.4\n"})  # fmt: skip
    losses, meta = read_training(tmp_path)
    assert losses["val_loss"].tolist() == [0.4] and meta["best_val_loss"] == 1e-3
    for text, message in ((b"", "not a loss curve"), (b"epoch,loss\n1,0.5\n", "lacks the column"),
                          (b"epoch,train_loss,val_loss\n", "has no epoch"),
                          (b"epoch,train_loss,val_loss\n1,x,0.4\n", "not numbers")):  # fmt: skip
        (tmp_path / "loss.csv").write_bytes(text)
        with pytest.raises(CapeError, match=f"loss.csv: .*{message}.*train it again"):
            read_training(tmp_path)
    (tmp_path / "loss.csv").write_bytes(b"epoch,train_loss,val_loss\n1,0.5,0.4\n")
    meta = json.loads((tmp_path / "meta.json").read_text())
    (tmp_path / "meta.json").write_text(json.dumps({**meta, "best_val_loss": None}))
    with pytest.raises(CapeError, match="`best_val_loss` is None, not a finite number"):
        read_training(tmp_path)
    checkpoint = Checkpointing(tmp_path / "checkpoint.pt", "abc")
    checkpoint.save({"model": {}, "losses": []})  # this training's fingerprint, keys missing
    with pytest.raises(CapeError, match=r"lacks optimiser, generator, .* not resumed; delete it"):
        checkpoint.load()
