"""Training helpers shared by the single-track and general trainings (experiments.potential.nets)."""

import pytest


def test_a_training_checkpoint_resumes_net_optimiser_and_schedule(tmp_path):
    """The value and potential trainings resume from their checkpoints (experiments.potential.nets)."""
    torch = pytest.importorskip("torch")
    from experiments.potential.nets import _resume, _save_atomic_torch

    def parts(seed):
        torch.manual_seed(seed)
        net = torch.nn.Linear(3, 2)
        opt = torch.optim.Adam(net.parameters(), lr=1e-2)
        sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=1e-2, total_steps=10)
        return net, opt, sched

    net, opt, sched = parts(0)
    net(torch.ones(1, 3)).sum().backward()
    opt.step()
    sched.step()
    ckpt = tmp_path / "value_ckpt.pt"
    assert _resume(ckpt, *parts(1), torch) is None
    _save_atomic_torch(
        {
            "net": net.state_dict(),
            "opt": opt.state_dict(),
            "sched": sched.state_dict(),
            "epoch": 1,
            "history": [0.5],
        },
        ckpt,
        torch,
    )
    net2, opt2, sched2 = parts(1)
    st = _resume(ckpt, net2, opt2, sched2, torch)
    assert st["epoch"] == 1 and st["history"] == [0.5]
    assert all(
        torch.equal(a, b) for a, b in zip(net.state_dict().values(), net2.state_dict().values())
    )
    assert sched2.state_dict()["last_epoch"] == sched.state_dict()["last_epoch"] == 1
    assert opt2.state_dict()["state"][0]["step"] == opt.state_dict()["state"][0]["step"]
