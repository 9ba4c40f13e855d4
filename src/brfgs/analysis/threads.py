"""PyTorch's thread count for a block of code (the analysis' sampling loops)."""

from __future__ import annotations

import torch

__all__ = ["torch_threads"]


class torch_threads:
    """Context manager: run with ``n`` PyTorch threads (loops over many small tensors run
    fastest single-threaded on a shared machine), then restore the previous count.
    ``n`` None or 0 leaves the count as it is."""

    def __init__(self, n: int | None) -> None:
        self.n = n
        self.prev: int | None = None

    def __enter__(self) -> "torch_threads":
        if self.n:
            self.prev = torch.get_num_threads()
            torch.set_num_threads(int(self.n))
        return self

    def __exit__(self, *exc) -> bool:
        if self.prev is not None:
            torch.set_num_threads(self.prev)
        return False
