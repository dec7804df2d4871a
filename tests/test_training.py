"""The one training loop (recon.training): schedules, best-checkpoint selection, and a resumed run
that equals the uninterrupted one."""
import math

import numpy as np
import pytest
import torch

from recon.errors import ReconError
from recon.training import Schedule, Trainer, epoch_batches


def test_schedules():
    cos = Schedule()
    assert cos(0.0) == 1.0 and cos(1.0) == 0.0 and cos(0.5) == pytest.approx(0.5) and cos(2.0) == 0.0
    floor = Schedule(floor=0.02)
    assert floor(1.0) == pytest.approx(0.02) and floor(0.5) == pytest.approx(0.51)
    one = Schedule(warmup=0.3, start=1 / 25, floor=1 / 25 / 1e4)
    assert one(0.0) == pytest.approx(1 / 25) and one(0.3) == pytest.approx(1.0) and one(1.0) == pytest.approx(4e-6)
    factors = [one(i / 100) for i in range(101)]
    assert all(a <= b for a, b in zip(factors[:30], factors[1:31]))
    assert all(a >= b for a, b in zip(factors[30:], factors[31:]))
    # PyTorch's OneCycleLR learning rates, to within the one-step placement of its peak
    opt = torch.optim.SGD([torch.zeros(1, requires_grad=True)], lr=1.0)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, 1.0, total_steps=200, cycle_momentum=False)
    ref = []
    for _ in range(200):
        ref.append(opt.param_groups[0]["lr"])
        opt.step()
        sched.step()
    assert max(abs(r - one(i / 200)) for i, r in enumerate(ref)) < 0.02


def _problem(seed=0):
    torch.manual_seed(seed)
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(40, 3, generator=g)
    y = x @ torch.tensor([1.0, -2.0, 0.5]) + 0.1 * torch.randn(40, generator=g)
    net = torch.nn.Sequential(torch.nn.Linear(3, 8), torch.nn.Dropout(0.2), torch.nn.Linear(8, 1))
    return net, x, y


def _run(out_dir, steps=12, stop_at=None):
    net, x, y = _problem()
    opt = torch.optim.Adam(net.parameters(), lr=0.05)
    trainer = Trainer({"net": net}, opt, steps, eval_every=4, out_dir=out_dir, select="val_loss",
                      config={"lr": 0.05}, steps_per_epoch=4, progress=False)
    calls = []

    def step(idx):
        if stop_at is not None and trainer.step == stop_at:
            raise KeyboardInterrupt  # Ctrl-C mid-epoch
        net.train()
        calls.append(trainer.step)
        return ((net(x[idx])[:, 0] - y[idx]) ** 2).mean(), {"n": float(len(idx))}

    def validate():
        net.eval()
        with torch.no_grad():
            return {"val_loss": float(((net(x)[:, 0] - y) ** 2).mean())}

    log = trainer.fit(epoch_batches(len(x), 10, trainer.step), step, validate)
    return net, log, trainer, calls


def test_an_interrupted_run_resumes_to_the_same_weights(tmp_path):
    whole, log, _, _ = _run(None)
    with pytest.raises(KeyboardInterrupt):
        _run(tmp_path, stop_at=6)  # checkpointed at step 4 (the end of the first epoch)
    resumed, log2, trainer, calls = _run(tmp_path)
    assert trainer.resumed and calls[0] == 4
    for a, b in zip(whole.state_dict().values(), resumed.state_dict().values(), strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    assert [r["val_loss"] for r in log["history"]] == pytest.approx([r["val_loss"] for r in log2["history"]], abs=0)
    rows = log2["history"]
    assert [r["step"] for r in rows] == [4, 8, 12] and rows[0]["epoch"] == 1.0 and rows[0]["n"] == 10.0
    assert log2["best"] == min(r["val_loss"] for r in rows)
    assert (tmp_path / "best.pt").exists() and (tmp_path / "curve.json").exists()


def test_the_best_checkpoint_is_kept_and_other_settings_are_refused(tmp_path):
    net, log, trainer, _ = _run(tmp_path)
    best = min(log["history"], key=lambda r: r["val_loss"])
    ck = torch.load(tmp_path / "best.pt", weights_only=True)
    assert ck["step"] == best["step"] and ck["metrics"]["val_loss"] == best["val_loss"]
    trainer.load_best()
    torch.testing.assert_close(net.state_dict()["0.weight"], ck["net"]["0.weight"])
    net2, _, _ = _problem()
    with pytest.raises(ReconError, match="other settings"):
        Trainer({"net": net2}, torch.optim.Adam(net2.parameters()), 12, out_dir=tmp_path, config={"lr": 1.0})


def test_the_schedule_sets_each_parameter_groups_rate():
    a, b = torch.zeros(1, requires_grad=True), torch.zeros(1, requires_grad=True)
    opt = torch.optim.SGD([{"params": [a], "lr": 1.0}, {"params": [b], "lr": 0.1}])
    seen = []
    trainer = Trainer({}, opt, 4, schedule=Schedule(), progress=False)

    def step(_):
        seen.append([g["lr"] for g in opt.param_groups])
        return (a + b).sum()

    trainer.fit(iter(range(10)), step)
    assert seen[0] == [1.0, 0.1] and seen[2] == pytest.approx([0.5, 0.05])
    assert all(lr[1] == pytest.approx(0.1 * lr[0]) for lr in seen)


def test_epoch_batches_resume_where_they_stopped():
    torch.manual_seed(0)
    whole = [b.tolist() for b in epoch_batches(10, 3, epochs=2)]
    assert len(whole) == 6 and sorted(sum(whole[:3], [])) != list(range(10))  # 9 of 10: the last is dropped
    torch.manual_seed(0)
    state = torch.get_rng_state()
    torch.manual_seed(0)
    first = next(epoch_batches(10, 3))
    assert first.tolist() == whole[0]
    torch.set_rng_state(state)  # the state at the start of epoch 0 ...
    assert [b.tolist() for b in epoch_batches(10, 3, start_step=1, epochs=1)] == whole[1:3]  # ... skips a batch
    rng = np.random.default_rng(5)
    it = epoch_batches(7, 2, generator=rng)
    assert len({tuple(next(it).tolist()) for _ in range(3)}) == 3
    with pytest.raises(ReconError, match="cannot fill one batch"):
        next(epoch_batches(2, 3))
    assert math.isclose(Schedule(floor=0.5)(0.0), 1.0)
