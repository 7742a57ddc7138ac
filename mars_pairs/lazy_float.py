"""A float32 tensor held as uint8 until its values are needed.

DataLoader workers send batches to the main process through shared memory, and on a VM
fresh shared memory is the dearest part of a worker's work (~0.75 ms/MB here, against ~10 ms
to decode a sample). Image fields are exactly ``uint8 / divisor``, so a worker hands out
:class:`Uint8AsFloat32` tensors: float32 tensors in every respect (dtype, shape, every torch
operation, ``.numpy()``, pickling, ``torch.save``) whose values are made from the uint8 twin on
first use. Between processes (``multiprocessing``'s ForkingPickler, which DataLoader queues
use) an unused one travels as its uint8 twin, a quarter of the bytes, and arrives as a plain
float32 tensor; once used, it travels as its float32 values.
"""

from __future__ import annotations

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


class Uint8AsFloat32(torch.Tensor):
    """The float32 tensor ``uint8 / divisor``, computed on first use (CPU only)."""

    __torch_function__ = torch._C._disabled_torch_function_impl

    uint8: torch.Tensor
    divisor: float
    _values: torch.Tensor | None

    @staticmethod
    def __new__(cls, uint8: torch.Tensor, divisor: float) -> Uint8AsFloat32:
        if uint8.dtype != torch.uint8 or uint8.device.type != "cpu":
            raise ValueError(f"expected a CPU uint8 tensor, got {uint8.dtype} on {uint8.device}")
        self = torch.Tensor._make_wrapper_subclass(
            cls, uint8.shape, dtype=torch.float32, device=uint8.device
        )
        self.uint8, self.divisor, self._values = uint8, float(divisor), None
        return self

    def __init__(self, uint8: torch.Tensor, divisor: float) -> None:  # fields set in __new__
        pass

    @property
    def materialized(self) -> bool:
        """Whether the float32 values exist yet (any use makes them)."""
        return self._values is not None

    def values(self) -> torch.Tensor:
        """The float32 values, as a plain tensor (made once, then shared by every use)."""
        if self._values is None:
            self._values = divided(self.uint8, self.divisor)
        return self._values

    @classmethod
    def __torch_dispatch__(
        cls, func: Any, types: Any, args: tuple = (), kwargs: dict | None = None
    ) -> Any:
        def real(x: Any) -> Any:
            return x.values() if isinstance(x, cls) else x

        return func(*pytree.tree_map(real, args), **pytree.tree_map(real, kwargs or {}))

    # what bypasses dispatch: storage and numpy access, printing, copying, pickling
    def numpy(self, *, force: bool = False) -> np.ndarray:
        return self.values().numpy(force=force)

    def __array__(self, dtype: Any = None, copy: bool | None = None) -> np.ndarray:
        return np.asarray(self.values().numpy(), dtype=dtype)

    def data_ptr(self) -> int:
        return self.values().data_ptr()

    def untyped_storage(self) -> torch.UntypedStorage:
        return self.values().untyped_storage()

    def _typed_storage(self) -> Any:
        return self.values()._typed_storage()

    def __repr__(self, **kwargs: Any) -> str:
        return repr(self.values())

    def __deepcopy__(self, memo: dict) -> torch.Tensor:
        return self.values().clone()

    def __reduce_ex__(self, protocol: Any) -> Any:
        return self.values().__reduce_ex__(protocol)  # pickle, torch.save: a plain tensor


def _reduce_between_processes(tensor: Uint8AsFloat32) -> tuple[Any, ...]:
    """ForkingPickler's reduction: the uint8 twin while unused, else the float32 values
    (each then shared as torch shares any tensor)."""
    if tensor.materialized:
        return (_same, (tensor.values(),))
    return (divided, (tensor.uint8, tensor.divisor))


ForkingPickler.register(Uint8AsFloat32, _reduce_between_processes)
