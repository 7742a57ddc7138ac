"""Uint8AsFloat32 behaves as the float32 tensor uint8 / divisor, and crosses processes as uint8."""

from __future__ import annotations

import copy
import io
import multiprocessing as mp
import pickle
from multiprocessing.reduction import ForkingPickler

import numpy as np
import pytest
import torch
from torch.utils.data import default_collate

from mars_pairs.torch.lazy_float import TransportBuffers, Uint8AsFloat32


@pytest.fixture
def uint8() -> torch.Tensor:
    return torch.from_numpy(np.random.default_rng(3).integers(0, 256, (2, 3, 4, 5), np.uint8))


def expected(uint8: torch.Tensor, divisor: float = 255.0) -> torch.Tensor:
    return torch.from_numpy(uint8.numpy() / np.float32(divisor))


def test_metadata_without_values(uint8: torch.Tensor) -> None:
    x = Uint8AsFloat32(uint8, 255.0)
    assert isinstance(x, torch.Tensor)
    assert x.dtype == torch.float32 and x.shape == uint8.shape and x.dim() == 4
    assert x.numel() == uint8.numel() and len(x) == 2 and not x.requires_grad
    assert not x.materialized  # metadata costs nothing
    with pytest.raises(ValueError, match="uint8"):
        Uint8AsFloat32(uint8.float(), 255.0)


def test_every_use_sees_the_float_values(uint8: torch.Tensor) -> None:
    ref = expected(uint8)

    def fresh() -> Uint8AsFloat32:
        return Uint8AsFloat32(uint8.clone(), 255.0)

    assert torch.equal(fresh(), ref) and torch.equal(fresh() + 1, ref + 1)
    assert torch.equal(2 * fresh(), 2 * ref) and torch.equal(fresh()[1, 2], ref[1, 2])
    assert torch.equal(torch.mean(fresh(), dim=(1, 2, 3)), ref.mean(dim=(1, 2, 3)))
    assert torch.equal(torch.stack([fresh(), fresh()]), torch.stack([ref, ref]))
    assert torch.equal(fresh().to(torch.float64), ref.double())
    assert np.array_equal(fresh().numpy(), ref.numpy())
    assert np.array_equal(np.asarray(fresh()), ref.numpy())
    assert fresh()[0, 0, 0].tolist() == ref[0, 0, 0].tolist()
    conv = torch.nn.functional.conv2d(fresh(), torch.ones(1, 3, 1, 1))
    assert torch.allclose(conv, ref.sum(1, keepdim=True))
    assert repr(fresh()) == repr(ref)
    assert torch.equal(copy.deepcopy(fresh()), ref)
    assert torch.equal(default_collate([fresh()[0], fresh()[1]]), ref)
    # in place, and through a view: later uses see the change
    x = fresh()
    x.mul_(2)
    assert torch.equal(x, ref * 2)
    x = fresh()
    x[0].zero_()
    assert float(x[0].abs().sum()) == 0.0 and torch.equal(x[1], ref[1])


def test_pickle_and_torch_save_give_plain_tensors(uint8: torch.Tensor) -> None:
    x = Uint8AsFloat32(uint8, 1.0)
    back = pickle.loads(pickle.dumps(x))
    assert type(back) is torch.Tensor and torch.equal(back, expected(uint8, 1.0))
    buf = io.BytesIO()
    torch.save({"v": Uint8AsFloat32(uint8, 255.0)}, buf)
    buf.seek(0)
    loaded = torch.load(buf)["v"]  # weights_only: no foreign globals in the file
    assert type(loaded) is torch.Tensor and torch.equal(loaded, expected(uint8))


def _receive(queue: mp.Queue, results: mp.Queue) -> None:
    batch = queue.get()
    # numpy arrays travel by value: this process may exit before the parent reads them
    results.put({k: (type(v).__name__, v.dtype, v.numpy().copy()) for k, v in batch.items()})


@pytest.mark.parametrize("context", ["fork", "spawn"])
def test_crosses_processes_as_uint8_and_arrives_as_float32(
    uint8: torch.Tensor, context: str
) -> None:
    ctx = mp.get_context(context)
    pool = TransportBuffers()
    shared = pool.empty(tuple(uint8.shape))
    shared.copy_(uint8)
    used = Uint8AsFloat32(uint8.clone(), 255.0)
    used.add_(0)  # materialized: travels as its float32 values
    queue, results = ctx.Queue(), ctx.Queue()
    proc = ctx.Process(target=_receive, args=(queue, results))
    proc.start()
    queue.put({"lazy": Uint8AsFloat32(shared, 255.0, pooled=True), "used": used})
    got = results.get(timeout=60)
    proc.join(timeout=60)
    for key in ("lazy", "used"):
        name, dtype, values = got[key]
        assert name == "Tensor" and dtype == torch.float32
        assert np.array_equal(values, expected(uint8).numpy())
    # the receiver marked the pooled buffer copied out: the pool hands the same memory back
    again = pool.empty(tuple(uint8.shape))
    assert again.data_ptr() == shared.data_ptr()


def test_pool_reuses_only_received_buffers(uint8: torch.Tensor) -> None:
    pool = TransportBuffers(max_per_size=2)
    shape = tuple(uint8.shape)
    a = pool.empty(shape)
    b = pool.empty(shape)  # a was never received: new memory
    assert a.data_ptr() != b.data_ptr()
    a.copy_(uint8)
    x = Uint8AsFloat32(a, 255.0, pooled=True)
    received = pickle.loads(ForkingPickler.dumps(x))  # in-process round trip: marks a
    assert torch.equal(received, expected(uint8))
    assert pool.empty(shape).data_ptr() == a.data_ptr()
    # sent unused, the sender's tensor is spent: its buffer may hold another batch now
    with pytest.raises(RuntimeError, match="sent to another process"):
        x.sum()
    # past max_per_size the oldest unreceived buffer is forgotten, not overwritten
    c = pool.empty(shape)
    assert c.data_ptr() not in (a.data_ptr(), b.data_ptr())
