"""FloAffDataModule: the base LightningDataModule (splits, loaders, collate, transforms)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import partial
from typing import Any, Literal

import lightning as L
import torch
from lightning.pytorch.utilities.exceptions import MisconfigurationException
from torch.utils.data import DataLoader, Dataset

from floaff_zoo.contract import Sample, collate_samples

Split = Literal["train", "val", "test", "predict"]


class FloAffDataModule(L.LightningDataModule):
    """Shared machinery: ``setup`` fills ``self.datasets[split]``; loaders collate to fixed sizes.

    Args:
        batch_size: samples per batch (eval loaders use ``eval_batch_size`` when set).
        eval_batch_size: batch size of val/test/predict loaders (MoMa-Kitchen's official code uses 64).
        num_workers: DataLoader workers.
        num_points: scene points per sample after collation (``None`` = largest in the batch).
        num_floor: floor points per sample after collation (``None`` = largest in the batch).
        collate_mode: ``resample`` (fast mode: exactly ``num_points`` valid points) or ``pad``
            (faithful mode: truncate/zero-pad with masks).
        seed: seed of splits, resampling and augmentation.
    """

    def __init__(
        self,
        batch_size: int = 8,
        eval_batch_size: int | None = None,
        num_workers: int = 0,
        num_points: int | None = 4096,
        num_floor: int | None = None,
        collate_mode: Literal["pad", "resample"] = "resample",
        seed: int = 0,
    ) -> None:
        super().__init__()
        self.batch_size = batch_size
        self.eval_batch_size = eval_batch_size or batch_size
        self.num_workers = num_workers
        self.num_points = num_points
        self.num_floor = num_floor
        self.collate_mode = collate_mode
        self.seed = seed
        self.datasets: dict[str, Dataset] = {}

    def collate_fn(self, split: str) -> Callable[[Sequence[Sample]], dict[str, Any]]:
        # eval splits resample with a fixed seed so metrics are repeatable; train draws fresh points
        offsets = {"val": 1, "test": 2, "predict": 3}
        gen = torch.Generator().manual_seed(self.seed * 10 + offsets[split]) if split in offsets else None
        return partial(
            collate_samples, num_points=self.num_points, num_floor=self.num_floor, mode=self.collate_mode,
            generator=gen,
        )

    def _dataloader(self, split: str) -> DataLoader:
        ds = self.datasets.get(split)
        if ds is None:
            raise MisconfigurationException(
                f"{type(self).__name__}: no '{split}' split was set up (available: {sorted(self.datasets)})"
            )
        if len(ds) == 0:
            raise MisconfigurationException(f"{type(self).__name__}: the '{split}' split is empty")
        return DataLoader(
            ds,
            batch_size=self.batch_size if split == "train" else self.eval_batch_size,
            shuffle=split == "train",
            num_workers=self.num_workers,
            persistent_workers=self.num_workers > 0,
            collate_fn=self.collate_fn(split),
            generator=torch.Generator().manual_seed(self.seed) if split == "train" else None,
        )

    def train_dataloader(self) -> DataLoader:
        return self._dataloader("train")

    def val_dataloader(self) -> DataLoader:
        return self._dataloader("val")

    def test_dataloader(self) -> DataLoader:
        return self._dataloader("test")

    def predict_dataloader(self) -> DataLoader:
        return self._dataloader("predict" if "predict" in self.datasets else "test")
