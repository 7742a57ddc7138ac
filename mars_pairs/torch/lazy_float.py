"""A float32 tensor held as uint8 until its values are needed.

DataLoader workers send batches to the main process through shared memory, and on a VM
fresh shared memory is the dearest part of a worker's work (~0.75 ms/MB here, against ~10 ms
to decode a sample). Image fields are exactly ``uint8 / divisor``, so a worker hands out
:class:`Uint8AsFloat32` tensors: float32 tensors in every respect (dtype, shape, every torch
operation, ``.numpy()``, pickling, ``torch.save``) whose values are made from the uint8 twin on
first use. Between processes (``multiprocessing``'s ForkingPickler, which DataLoader queues
use) an unused one travels as its uint8 twin, a quarter of the bytes, and arrives as a plain
float32 tensor; once used, it travels as its float32 values.

The twin's shared memory can come from :class:`TransportBuffers`, which reuses a buffer once
the receiving process has marked it copied out, so a worker's steady state touches no fresh
shared memory at all.

Built on torch's tensor-subclass machinery (``Tensor._make_wrapper_subclass``,
``__torch_dispatch__``, ``torch.utils._pytree``), underscored but the documented way to write
such subclasses since torch 1.13; ``tests/test_lazy_float.py`` checks every behaviour above
on the installed torch.
"""

from __future__ import annotations

import os
from collections import OrderedDict
from multiprocessing.reduction import ForkingPickler
from typing import Any

import numpy as np
import torch
import torch.multiprocessing  # registers torch's own ForkingPickler reductions
from torch.utils import _pytree as pytree


def divided(uint8: torch.Tensor, divisor: float) -> torch.Tensor:
    """``uint8 / divisor`` as a new float32 tensor (numpy's division, so bit for bit what
    ``np.divide(uint8, np.float32(divisor))`` gives; numpy memory is huge-page backed)."""
    out = np.empty(tuple(uint8.shape), dtype=np.float32)
    np.divide(uint8.numpy(), np.float32(divisor), out=out)
    return torch.from_numpy(out)


def _same(tensor: torch.Tensor) -> torch.Tensor:
    return tensor


def _arrive(uint8: torch.Tensor, divisor: float) -> torch.Tensor:
    """Unpickling an unused :class:`Uint8AsFloat32` from a :class:`TransportBuffers` buffer:
    the float32 values, then the buffer's flag byte set so the sender may reuse it."""
    out = divided(uint8, divisor)
    storage = uint8.untyped_storage()
    flag = torch.empty(0, dtype=torch.uint8).set_(storage, storage.nbytes() - 1, (1,))
    flag.fill_(1)
    return out


class TransportBuffers:
    """Shared-memory uint8 buffers one process reuses for outgoing :class:`Uint8AsFloat32`.

    Each buffer is a shared storage with one trailing flag byte, which the receiving process
    sets once it has copied the values out (``_arrive``); only flagged buffers are handed out
    again. Per process (a forked child starts empty: the parent's buffers are not its own).
    At most ``max_per_size`` buffers of one size are kept; past that the oldest unflagged one
    is forgotten (a batch never received costs memory, never correctness).
    """

    def __init__(self, max_per_size: int = 8) -> None:
        self.max_per_size = max_per_size
        self._pid = -1
        self._buffers: dict[int, OrderedDict[int, torch.Tensor]] = {}

    def empty(self, shape: tuple[int, ...]) -> torch.Tensor:
        """A uint8 tensor of ``shape`` in a free (or new) shared buffer, contents undefined."""
        if self._pid != os.getpid():
            self._buffers, self._pid = {}, os.getpid()
        nbytes = int(np.prod(shape))
        ring = self._buffers.setdefault(nbytes, OrderedDict())
        for key, buffer in ring.items():
            if int(buffer[nbytes]) == 1:
                ring.move_to_end(key)
                break
        else:
            buffer = torch.empty(nbytes + 1, dtype=torch.uint8).share_memory_()
            if len(ring) >= self.max_per_size:
                ring.popitem(last=False)
            ring[id(buffer)] = buffer
        buffer[nbytes] = 0
        return buffer[:nbytes].view(shape)

    def __getstate__(self) -> dict[str, Any]:
        return {"max_per_size": self.max_per_size, "_pid": -1, "_buffers": {}}


class Uint8AsFloat32(torch.Tensor):
    """The float32 tensor ``uint8 / divisor``, computed on first use (CPU only)."""

    __torch_function__ = torch._C._disabled_torch_function_impl

    uint8: torch.Tensor
    divisor: float
    pooled: bool
    _values: torch.Tensor | None
    _sent: bool

    @staticmethod
    def __new__(
        cls, uint8: torch.Tensor, divisor: float, *, pooled: bool = False
    ) -> Uint8AsFloat32:
        if uint8.dtype != torch.uint8 or uint8.device.type != "cpu":
            raise ValueError(f"expected a CPU uint8 tensor, got {uint8.dtype} on {uint8.device}")
        self = torch.Tensor._make_wrapper_subclass(
            cls, uint8.shape, dtype=torch.float32, device=uint8.device
        )
        self.uint8, self.divisor, self.pooled = uint8, float(divisor), pooled
        self._values, self._sent = None, False
        self._members: list[Uint8AsFloat32] = []
        return self

    def stacked_from(self, rows: list[Uint8AsFloat32]) -> Uint8AsFloat32:
        """Record that this tensor stacks ``rows`` (views of its buffer): sending it spends
        them too. Returns self."""
        self._members = list(rows)
        return self

    def __init__(self, uint8: torch.Tensor, divisor: float, *, pooled: bool = False) -> None:
        pass  # fields set in __new__

    @property
    def materialized(self) -> bool:
        """Whether the float32 values exist yet (any use makes them)."""
        return self._values is not None

    def materialize(self) -> torch.Tensor:
        """The float32 values, as a plain tensor (made once, then shared by every use)."""
        if self._values is None:
            if self._sent:
                raise RuntimeError(
                    "this tensor was sent to another process unused, and its shared buffer "
                    "(TransportBuffers) may hold another batch by now: use it before sending"
                )
            self._values = divided(self.uint8, self.divisor)
        return self._values

    @classmethod
    def __torch_dispatch__(
        cls, func: Any, types: Any, args: tuple = (), kwargs: dict | None = None
    ) -> Any:
        def real(x: Any) -> Any:
            return x.materialize() if isinstance(x, cls) else x

        return func(*pytree.tree_map(real, args), **pytree.tree_map(real, kwargs or {}))

    # what bypasses dispatch: storage and numpy access, printing, copying, pickling
    def numpy(self, *, force: bool = False) -> np.ndarray:
        return self.materialize().numpy(force=force)

    def __array__(self, dtype: Any = None, copy: bool | None = None) -> np.ndarray:
        return np.asarray(self.materialize().numpy(), dtype=dtype)

    def data_ptr(self) -> int:
        return self.materialize().data_ptr()

    def untyped_storage(self) -> torch.UntypedStorage:
        return self.materialize().untyped_storage()

    def _typed_storage(self) -> Any:
        return self.materialize()._typed_storage()

    def __repr__(self, **kwargs: Any) -> str:
        return repr(self.materialize())

    def __deepcopy__(self, memo: dict) -> torch.Tensor:
        return self.materialize().clone()

    def __reduce_ex__(self, protocol: Any) -> Any:
        return self.materialize().__reduce_ex__(protocol)  # pickle, torch.save: a plain tensor


def _reduce_between_processes(tensor: Uint8AsFloat32) -> tuple[Any, ...]:
    """ForkingPickler's reduction: the uint8 twin while unused, else the float32 values
    (each then shared as torch shares any tensor). A pooled twin is handed over: the tensor
    is spent in this process (its buffer returns to the pool once the receiver has it)."""
    if tensor.materialized:
        return (_same, (tensor.materialize(),))
    if not tensor.pooled:
        return (divided, (tensor.uint8, tensor.divisor))
    for spent in (tensor, *tensor._members):
        spent._sent = True
    return (_arrive, (tensor.uint8, tensor.divisor))


ForkingPickler.register(Uint8AsFloat32, _reduce_between_processes)
