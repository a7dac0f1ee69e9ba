"""algorithms/optim.py against torch.optim: the same steps bit for bit, the same state dict, either loads the other."""

from __future__ import annotations

import pytest
import torch

from algorithms.optim import Adam

CASES = [  # (torch class, decoupled, weight decay)
    (torch.optim.Adam, False, 0.0),
    (torch.optim.Adam, False, 0.05),
    (torch.optim.AdamW, True, 0.0),
    (torch.optim.AdamW, True, 0.01),
]


def _params(seed: int) -> list[torch.nn.Parameter]:
    g = torch.Generator().manual_seed(seed)
    return [torch.nn.Parameter(torch.randn(shape, generator=g)) for shape in ((7, 5), (5,), ())]


@pytest.mark.parametrize("cls,decoupled,decay", CASES)
def test_every_step_equals_torchs_bit_for_bit(cls, decoupled, decay):
    ours, theirs = _params(0), _params(0)
    a = Adam(ours, lr=2e-3, betas=(0.7, 0.95), weight_decay=decay, decoupled=decoupled)
    b = cls(theirs, lr=2e-3, betas=(0.7, 0.95), weight_decay=decay)
    ga, gb = torch.Generator().manual_seed(3), torch.Generator().manual_seed(3)
    for t in range(30):
        _drive(a, ours, range(t, t + 1), ga)
        _drive(b, theirs, range(t, t + 1), gb)
        for p, q in zip(ours, theirs, strict=True):
            assert torch.equal(p, q), f"step {t}"
    sa, sb = a.state_dict(), b.state_dict()
    assert sa["param_groups"] == sb["param_groups"]
    assert sa["state"].keys() == sb["state"].keys()
    for i in sb["state"]:
        for key, value in sb["state"][i].items():
            assert sa["state"][i][key].dtype == value.dtype and torch.equal(sa["state"][i][key], value), (i, key)


@pytest.mark.parametrize("cls,decoupled,decay", CASES)
def test_a_checkpoint_of_either_resumes_in_the_other(cls, decoupled, decay):
    """Half the steps in one, a state dict through torch.save/torch.load, the rest in the other: the
    parameters end where torch alone takes them."""
    for first_ours in (True, False):
        reference = _params(1)
        ref = cls(reference, lr=2e-3, betas=(0.7, 0.95), weight_decay=decay)
        _drive(ref, reference, range(20), torch.Generator().manual_seed(5))

        params = _params(1)
        # the second starts from other hyper-parameters: loading must bring the first's
        ours = Adam(params, lr=1.0, betas=(0.5, 0.5), weight_decay=decay, decoupled=decoupled)
        theirs = cls(params, lr=1.0, betas=(0.5, 0.5), weight_decay=decay)
        first, second = (ours, theirs) if first_ours else (theirs, ours)
        first.param_groups[0]["betas"] = (0.7, 0.95)
        first.param_groups[0]["lr"] = 2e-3
        g = torch.Generator().manual_seed(5)
        _drive(first, params, range(10), g)
        saved = _round_trip(first.state_dict())
        second.load_state_dict(saved)
        assert tuple(second.param_groups[0]["betas"]) == (0.7, 0.95)
        _drive(second, params, range(10, 20), g)
        for p, q in zip(params, reference, strict=True):
            assert torch.equal(p, q), "ours first" if first_ours else "torch first"


def _drive(opt, params, steps: range, g: torch.Generator) -> None:
    """Gradients of growing and shrinking size, a parameter left without one on every third step, a
    learning rate that changes every step as the linear schedule changes it."""
    for t in steps:
        opt.zero_grad()
        for i, p in enumerate(params):
            if i == 1 and t % 3 == 0:
                continue
            p.grad = torch.randn(p.shape, generator=g) * 10.0 ** (t % 5 - 2)
        opt.param_groups[0]["lr"] = 2e-3 * (1 - t / 40)
        opt.step()


def _round_trip(state: dict) -> dict:
    import io

    buffer = io.BytesIO()
    torch.save(state, buffer)
    buffer.seek(0)
    return torch.load(buffer, weights_only=True)


def test_a_state_dict_of_another_shape_is_refused():
    a = Adam(_params(0), lr=1e-3, betas=(0.9, 0.999), weight_decay=0.0, decoupled=False)
    b = Adam(_params(0)[:2], lr=1e-3, betas=(0.9, 0.999), weight_decay=0.0, decoupled=False)
    with pytest.raises(ValueError, match="3 parameters, this optimiser 2"):
        b.load_state_dict(a.state_dict())
